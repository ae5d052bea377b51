"""Gradient-safe maths shared by the simulator.

Every function here has a finite value *and* a finite gradient everywhere,
including the usual singular points (zero-length vectors, omega -> 0). The
pattern, borrowed from brax's ``safe_norm``, is "double where": feed the
singular branch a harmless input so that neither the forward nor the backward
pass of the unused branch can produce inf or NaN.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

TWO_PI = 2.0 * math.pi


def wrap_angle(a: Tensor) -> Tensor:
    """Wrap angles (radians) to [-pi, pi). Gradient is 1 everywhere."""
    w = torch.remainder(a + math.pi, TWO_PI) - math.pi
    # remainder can round up to exactly 2 pi (a just below -pi), which would give +pi.
    return torch.where(w >= math.pi, w - TWO_PI, w)


def safe_norm(x: Tensor, dim: int = -1, eps: float = 1e-12) -> Tensor:
    """Euclidean norm along ``dim`` whose gradient at the zero vector is 0, not NaN."""
    sq = (x * x).sum(dim)
    nonzero = sq > eps
    return torch.where(nonzero, torch.sqrt(torch.where(nonzero, sq, torch.ones_like(sq))), torch.zeros_like(sq))


def safe_hypot(x: Tensor, y: Tensor, eps: float = 1e-12) -> Tensor:
    """``sqrt(x**2 + y**2)`` from two component tensors, gradient-safe at the origin."""
    sq = x * x + y * y
    nonzero = sq > eps
    return torch.where(nonzero, torch.sqrt(torch.where(nonzero, sq, torch.ones_like(sq))), torch.zeros_like(sq))


def safe_sinc(u: Tensor, eps: float = 1e-4) -> Tensor:
    """``sin(u) / u`` with the limit 1 at u = 0 and a finite gradient there.

    Below ``eps`` the second-order Taylor expansion ``1 - u^2 / 6`` is used; its
    error there is below ``eps**4 / 120``, far under float32 resolution.
    """
    small = u.abs() < eps
    u_safe = torch.where(small, torch.ones_like(u), u)
    return torch.where(small, 1.0 - u * u / 6.0, torch.sin(u_safe) / u_safe)


def rotate(x: Tensor, y: Tensor, theta: Tensor) -> tuple[Tensor, Tensor]:
    """Rotate vectors ``(x, y)`` counter-clockwise by ``theta`` (radians); all broadcast."""
    c, s = torch.cos(theta), torch.sin(theta)
    return c * x - s * y, s * x + c * y
