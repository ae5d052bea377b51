"""Dependency-free C99 export of a torchnav actor, for microcontrollers.

``export_c(net, out_dir, name)`` writes ``<name>.h``, ``<name>.c`` (weights as ``static const``
float, float16 or int8 arrays, normalisation baked in, ``<name>_forward`` with two static
buffers and no malloc) and ``<name>_test.c``, which ``verify_c`` compiles and compares with
PyTorch. The files' contents: docs/export.md."""

from __future__ import annotations

import keyword
import os
import re
import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from ..checkpoint import write_atomic
from .common import Network, compare, outputs, run_tool

C_FLAGS = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2"]
_C_KEYWORDS = set("auto break case char const continue default do double else enum extern float for goto if inline int "
                  "long register restrict return short signed sizeof static struct switch typedef union unsigned void "
                  "volatile while _Bool _Complex _Imaginary".split())


def check_name(name: str) -> str:
    """``name`` if it is a valid C identifier prefix (``[A-Za-z_][A-Za-z0-9_]*``, not a keyword), else ``ValueError``."""
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name) or name in _C_KEYWORDS or keyword.iskeyword(name):
        raise ValueError(f"--name must be a C identifier (letters, digits, '_', not starting with a digit), got {name!r}")
    return name


def c_float(x: float) -> str:
    """A C float literal that round-trips the float32 value ``x`` (9 significant digits)."""
    s = "%.9g" % float(np.float32(x))
    if not np.isfinite(float(x)):
        raise ValueError(f"cannot write non-finite value {x} as a C literal")
    if not any(ch in s for ch in ".en"):
        s += ".0"
    return s + "f"


def _array(name: str, values: np.ndarray, comment: str, per_line: int = 8) -> str:
    """A ``static const`` C array: float literals for float arrays, hex for uint16 (float16 bits), decimal for int8."""
    values = np.asarray(values)
    if values.dtype == np.uint16:
        ctype, flat, per_line = "uint16_t", ["0x%04x" % v for v in values.reshape(-1)], 12
    elif values.dtype == np.int8:
        ctype, flat, per_line = "int8_t", ["%d" % v for v in values.reshape(-1)], 16
    else:
        ctype, flat = "float", [c_float(v) for v in values.astype(np.float32).reshape(-1)]
    rows = [", ".join(flat[i:i + per_line]) for i in range(0, len(flat), per_line)]
    body = ",\n    ".join(rows)
    return f"/* {comment} */\nstatic const {ctype} {name}[{len(flat)}] = {{\n    {body}\n}};\n"


_WEIGHT_C = {"float32": "float", "float16": "uint16_t (float16 bits)", "int8": "int8_t with a float scale per row"}


def render_header(net: Network, name: str) -> str:
    N, fp = name.upper(), net.footprint()
    discrete = net.output == "argmax"
    lines = [
        f"/* {name}.h - torchnav policy exported by `python -m torchnav.export` (torchnav {net.metadata.get('torchnav_version', '?')}).",
        f" * task {net.metadata.get('task', '?')}, algorithm {net.metadata.get('algorithm', '?')}, "
        f"layers {net.obs_size} -> {' -> '.join(str(w.shape[0]) for w, _ in net.layers)}, "
        f"{net.activation}, {'argmax over an action table' if discrete else 'tanh head'}.",
        f" * Weights stored as {_WEIGHT_C[net.weights]}; biases, normalisation and arithmetic in float.",
        f" * Constants {fp['flash_bytes']} bytes (flash), buffers {fp['ram_bytes']} bytes (RAM, static), {fp['macs']} multiply-adds per call.",
        " * Not reentrant: the working buffers are static (call it from one context only). */",
        f"#ifndef {N}_H", f"#define {N}_H", "",
        "#ifdef __cplusplus", 'extern "C" {', "#endif", "",
        f"/* Raw observation length: exactly what the torchnav env produces (normalisation is inside {name}_forward). */",
        f"#define {N}_OBS_SIZE {net.obs_size}",
        f"/* Floats written to `action`: {'the action_table row of the best action' if discrete else 'actions in [-1, 1]'}. */",
        f"#define {N}_ACT_SIZE {net.act_size}",
    ]
    if discrete:
        lines += ["/* Number of discrete actions (Q-values). */", f"#define {N}_NUM_ACTIONS {net.out_size}"]
    lines += ["", f"/* obs: {N}_OBS_SIZE floats; action: {N}_ACT_SIZE floats. */",
              f"void {name}_forward(const float *obs, float *action);"]
    if discrete:
        lines += [f"/* Index in [0, {N}_NUM_ACTIONS) of the best action (first on ties, as torch.argmax). */",
                  f"int {name}_forward_index(const float *obs);",
                  f"/* All {N}_NUM_ACTIONS Q-values. */",
                  f"void {name}_q_values(const float *obs, float *q);",
                  f"/* The command of each action, ({N}_NUM_ACTIONS, {N}_ACT_SIZE) row-major. */",
                  f"extern const float {name}_action_table[{net.action_table.size}];"]
    lines += ["", "#ifdef __cplusplus", "}", "#endif", "", f"#endif /* {N}_H */", ""]
    return "\n".join(lines)


def _dense_source(net: Network, name: str, act: str) -> list[str]:
    """The layer function for the network's weight format: ``y = act(W x + b)``, sums in float in index order."""
    if net.weights == "float32":
        wtype, term, scale_arg, finish = "float", "row[i] * x[i]", "", "v += b[o];"
    elif net.weights == "float16":
        wtype, term, scale_arg, finish = "uint16_t", f"{name}_half(row[i]) * x[i]", "", "v += b[o];"
    else:
        wtype, term, scale_arg, finish = "int8_t", "(float)row[i] * x[i]", "const float *s, ", "v = v * s[o] + b[o];"
    lines = []
    if net.weights == "float16":
        lines += [
            "/* float16 bits -> float, exactly. Cortex-M4F/M7 (gcc -mfp16-format=ieee) convert in one instruction;",
            " * elsewhere: put the exponent and mantissa into a float and rescale (2^112 turns half's bias of 15",
            " * into float's 127; float16 subnormals become float normals), then the sign. No inf/NaN are stored. */",
            f"static float {name}_half(uint16_t h)", "{",
            "#if defined(__ARM_FP16_FORMAT_IEEE)",
            "    __fp16 f;", "    memcpy(&f, &h, sizeof f);", "    return (float)f;",
            "#else",
            "    uint32_t bits = (uint32_t)(h & 0x7fffu) << 13;", "    float f;",
            "    memcpy(&f, &bits, sizeof f);", "    f *= 0x1p112f;",
            "    return (h & 0x8000u) ? -f : f;",
            "#endif", "}", ""]
    what = {"float32": "W (n_out, n_in) row-major", "float16": "W (n_out, n_in) row-major float16 bits",
            "int8": "W = s[o] * q, q (n_out, n_in) row-major int8, s[o] applied after the row sum"}[net.weights]
    lines += [
        f"/* y = act(W x + b); {what}; sums in float, in index order. */",
        f"static void {name}_dense(const {wtype} *w, {scale_arg}const float *b, const float *x, float *y, int n_in, int n_out, int act)",
        "{", "    int o, i;", "    for (o = 0; o < n_out; ++o) {", f"        const {wtype} *row = w + o * n_in;",
        "        float v = 0.0f;", "        for (i = 0; i < n_in; ++i) {", f"            v += {term};", "        }",
        f"        {finish}", f"        y[o] = act ? ({act}) : v;", "    }", "}", ""]
    return lines


def render_source(net: Network, name: str) -> str:
    N = name.upper()
    act = "v > 0.0f ? v : 0.0f" if net.activation == "relu" else "tanhf(v)"
    needs_math = net.activation == "tanh" or net.output == "tanh"
    includes = [f'#include "{name}.h"'] + (["#include <math.h>"] if needs_math else [])
    if net.weights != "float32":
        includes.append("#include <stdint.h>")
    if net.weights == "float16":
        includes.append("#include <string.h>")
    parts = [f'/* {name}.c - generated by `python -m torchnav.export`; see {name}.h. Do not edit. */',
             *includes, "",
             f"#define {N}_MAX_WIDTH {max(net.max_width, net.obs_size)}", "",
             _array(f"{name}_obs_loc", net.obs_loc, "observation offset: x = (obs - obs_loc) / obs_scale"),
             _array(f"{name}_obs_scale", net.obs_scale, "observation scale")]
    for k, (w, b) in enumerate(net.layers):
        o, i = w.shape
        if net.weights == "float32":
            parts.append(_array(f"{name}_w{k}", w, f"layer {k} weight ({o}, {i}) row-major: w[o * {i} + i]"))
        elif net.weights == "float16":
            parts.append(_array(f"{name}_w{k}", net.stored[k], f"layer {k} weight ({o}, {i}) row-major float16 bits: w[o * {i} + i]"))
        else:
            q, scale = net.stored[k]
            parts += [_array(f"{name}_w{k}", q, f"layer {k} weight ({o}, {i}) row-major int8: W[o][i] = s{k}[o] * w[o * {i} + i]"),
                      _array(f"{name}_s{k}", scale, f"layer {k} scale per output row ({o},)")]
        parts.append(_array(f"{name}_b{k}", b, f"layer {k} bias ({o},)"))
    if net.output == "argmax":
        t = _array(f"{name}_action_table", net.action_table, f"command of each action ({net.out_size}, {net.act_size}) row-major")
        parts.append(t.replace("static const float", "const float", 1))
    parts += [f"static float {name}_buf_a[{N}_MAX_WIDTH];", f"static float {name}_buf_b[{N}_MAX_WIDTH];", ""]
    parts += _dense_source(net, name, act)
    parts += [
        "/* The last layer's outputs (actions before the tanh head, or Q-values); returns a pointer to a static buffer. */",
        f"static const float *{name}_network(const float *obs)", "{",
        f"    float *x = {name}_buf_a, *y = {name}_buf_b, *t;", "    int i;",
        f"    for (i = 0; i < {N}_OBS_SIZE; ++i) {{", f"        x[i] = (obs[i] - {name}_obs_loc[i]) / {name}_obs_scale[i];", "    }",
    ]
    last = len(net.layers) - 1
    for k, (w, _) in enumerate(net.layers):
        o, i = w.shape
        scale = f"{name}_s{k}, " if net.weights == "int8" else ""
        parts.append(f"    {name}_dense({name}_w{k}, {scale}{name}_b{k}, x, y, {i}, {o}, {0 if k == last else 1});")
        parts.append("    t = x; x = y; y = t;")
    parts += ["    (void)y;", "    return x;", "}", ""]
    if net.output == "tanh":
        parts += [f"void {name}_forward(const float *obs, float *action)", "{",
                  f"    const float *y = {name}_network(obs);", "    int i;",
                  f"    for (i = 0; i < {N}_ACT_SIZE; ++i) {{", "        action[i] = tanhf(y[i]);", "    }", "}", ""]
    else:
        parts += [f"void {name}_q_values(const float *obs, float *q)", "{",
                  f"    const float *y = {name}_network(obs);", "    int i;",
                  f"    for (i = 0; i < {N}_NUM_ACTIONS; ++i) {{", "        q[i] = y[i];", "    }", "}", "",
                  f"int {name}_forward_index(const float *obs)", "{",
                  f"    const float *y = {name}_network(obs);", "    int i, best = 0;",
                  f"    for (i = 1; i < {N}_NUM_ACTIONS; ++i) {{", "        if (y[i] > y[best]) {", "            best = i;",
                  "        }", "    }", "    return best;", "}", "",
                  f"void {name}_forward(const float *obs, float *action)", "{",
                  f"    int best = {name}_forward_index(obs), i;",
                  f"    for (i = 0; i < {N}_ACT_SIZE; ++i) {{", f"        action[i] = {name}_action_table[best * {N}_ACT_SIZE + i];",
                  "    }", "}", ""]
    return "\n".join(parts)


def render_test(net: Network, name: str) -> str:
    N = name.upper()
    discrete = net.output == "argmax"
    out = ([f"        float q[{N}_NUM_ACTIONS];", f"        printf(\"%d\", {name}_forward_index(obs));",
            f"        {name}_forward(obs, action);",
            f"        for (i = 0; i < {N}_ACT_SIZE; ++i) printf(\" %.9g\", (double)action[i]);",
            f"        {name}_q_values(obs, q);",
            f"        for (i = 0; i < {N}_NUM_ACTIONS; ++i) printf(\" %.9g\", (double)q[i]);"] if discrete else
           [f"        {name}_forward(obs, action);",
            f"        for (i = 0; i < {N}_ACT_SIZE; ++i) printf(\"%s%.9g\", i ? \" \" : \"\", (double)action[i]);"])
    head = "index, action, Q-values" if discrete else "action"
    return "\n".join([
        f"/* {name}_test.c - reads observations ({N}_OBS_SIZE whitespace-separated floats each) from stdin",
        f" * and prints one line per observation: {head} (%.9g). Build: cc -std=c99 -O2 {name}.c {name}_test.c -lm */",
        "#include <stdio.h>", f'#include "{name}.h"', "", "int main(void)", "{",
        f"    float obs[{N}_OBS_SIZE], action[{N}_ACT_SIZE];", "    int i;", "    for (;;) {",
        f"        for (i = 0; i < {N}_OBS_SIZE; ++i) {{", "            if (scanf(\"%f\", &obs[i]) != 1) {",
        "                if (i == 0) return 0;",
        f"                fprintf(stderr, \"{name}_test: the last observation has %d values, expected {N}_OBS_SIZE = %d\\n\", i, {N}_OBS_SIZE);",
        "                return 1; /* a partial observation is an error */", "            }", "        }",
        *out, "        printf(\"\\n\");", "    }", "}", ""])


def export_c(net: Network, out_dir: str | Path, name: str = "policy") -> list[Path]:
    """Write ``<name>.h``, ``<name>.c`` and ``<name>_test.c`` into ``out_dir`` (created if missing); returns their paths."""
    check_name(name)
    return write_files(out_dir, {f"{name}.h": render_header(net, name), f"{name}.c": render_source(net, name), f"{name}_test.c": render_test(net, name)})


def write_files(out_dir: str | Path, files: dict[str, str]) -> list[Path]:
    """Write ``{file name: text}`` into ``out_dir`` (created if missing); returns the paths in order."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for fname, text in files.items():
        write_atomic(out_dir / fname, text)  # a failed write keeps the previous file whole
        paths.append(out_dir / fname)
    return paths


def find_compiler() -> str | None:
    """The C compiler: ``$CC`` if set, else ``cc``, ``gcc`` or ``clang`` on PATH; ``None`` if there is none."""
    for c in ([os.environ["CC"]] if os.environ.get("CC") else []) + ["cc", "gcc", "clang"]:
        if shutil.which(c):
            return c
    return None


def compile_test(out_dir: str | Path, name: str = "policy", compiler: str | None = None, workdir: str | Path | None = None) -> Path:
    """Compile ``<name>.c`` + ``<name>_test.c`` with ``C_FLAGS``; returns the executable. ``RuntimeError`` with the compiler output on failure."""
    compiler = compiler or find_compiler()
    if compiler is None:
        raise RuntimeError("no C compiler found (set CC, or install cc/gcc/clang)")
    out_dir = Path(out_dir)
    exe = Path(workdir or out_dir) / f"{name}_test"
    cmd = [compiler, *C_FLAGS, str(out_dir / f"{name}.c"), str(out_dir / f"{name}_test.c"), "-o", str(exe), "-lm"]
    run_tool(cmd, "C compilation")
    return exe


def run_c(exe: str | Path, obs: np.ndarray, net: Network) -> dict[str, np.ndarray]:
    """Run the compiled test program on ``obs`` ``(n, obs_size)``; keys as in ``common.reference``."""
    text = "\n".join(" ".join("%.9g" % v for v in row) for row in np.asarray(obs, dtype=np.float32))
    r = run_tool([str(exe)], "the C test program", input=text + "\n")
    vals = np.array([[float(v) for v in line.split()] for line in r.stdout.splitlines() if line.strip()], dtype=np.float64)
    if vals.shape[0] != obs.shape[0]:
        raise RuntimeError(f"{exe} printed {vals.shape[0]} lines for {obs.shape[0]} observations")
    return outputs(vals, net)


def verify_c(out_dir: str | Path, net: Network, ref: dict[str, np.ndarray], obs: np.ndarray, tolerance: float,
             name: str = "policy", compiler: str | None = None) -> dict[str, Any] | None:
    """Compile the exported files in a temporary folder and compare with PyTorch outputs ``ref`` on ``obs``.

    Returns ``common.compare``'s dict plus ``"compiler"``, or ``None`` when no C compiler is installed.
    """
    compiler = compiler or find_compiler()
    if compiler is None:
        return None
    with tempfile.TemporaryDirectory(prefix="torchnav_export_") as tmp:
        exe = compile_test(out_dir, name, compiler, workdir=tmp)
        res = compare(ref, run_c(exe, obs, net), tolerance)
    res["compiler"] = compiler
    return res
