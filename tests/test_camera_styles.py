"""Per-obstacle camera heights and colours from a map (``height``, ``color``), in the RGB render."""

import math

import pytest
import torch

from params import camera_params

from torchnav.maps import MapError, parse_map
from torchnav.sim import CameraParams, ObstacleStyles, camera_image, make_world

STYLED = {
    "size": [10.0, 10.0],
    "boxes": [{"center": [2.0, 0.0], "size": [0.2, 1.0], "height": 0.4, "color": [10, 200, 30]},
              {"center": [2.0, 2.0], "size": [0.2, 1.0]}],
    "circles": [{"center": [-2.0, 0.0], "radius": 0.3, "color": [250, 0, 250]}, [-3.0, 3.0, 0.2]],
}


def _rows_seen(cam: CameraParams, z: float, height: float) -> list[int]:
    """Rows of a column that meet a prism of ``height`` at depth ``z`` (closed form)."""
    return [i for i in range(cam.n_rows) if 0.0 <= cam.height + z * (0.5 * cam.n_rows - i - 0.5) / cam.focal <= height]


def test_map_styles_colour_and_raise_their_obstacles():
    spec = parse_map(STYLED)
    assert spec.styles.boxes == ((0.4, (10, 200, 30)), (None, None))
    assert spec.styles.circles == ((None, (250, 0, 250)), (None, None))
    world = spec.build_world(2)
    cam = camera_params(n_cols=9, n_rows=96, fov=math.radians(30))
    pose = torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, math.pi]])  # facing the styled box, then the styled circle
    depth, rgb = camera_image(pose, world, cam, styles=spec.styles)
    mid = cam.n_cols // 2
    for env, z, height, color in ((0, 1.9, 0.4, (10, 200, 30)), (1, 1.7, cam.circle_height, (250, 0, 250))):
        assert depth[env, mid].item() == pytest.approx(z, abs=1e-5)
        want = torch.tensor(color) / (1 + 0.08 * z)
        col = rgb[env, :, mid].to(torch.float32)
        drawn = [i for i in range(cam.n_rows) if (col[i] - want).abs().max() <= 1]
        assert drawn == _rows_seen(cam, z, height)
    # Without the map's styles the same obstacles take their kind's height and colour.
    _, plain = camera_image(pose, world, cam)
    want = torch.tensor(cam.box_color) / (1 + 0.08 * 1.9)
    col = plain[0, :, mid].to(torch.float32)
    assert [i for i in range(cam.n_rows) if (col[i] - want).abs().max() <= 1] == _rows_seen(cam, 1.9, cam.box_height)


def test_styles_apply_to_their_slots_only():
    """Style entry i is slot i of its kind; slots past the tuple keep the kind's defaults."""
    world = make_world(1, boxes=[[2.0, 0.0, 0.1, 2.0, 0.0], [1.0, 3.0, 0.1, 0.1, 0.0]])
    cam = camera_params(n_cols=3, n_rows=8, fov=0.3)
    styles = ObstacleStyles(boxes=((None, (1, 2, 3)),))
    table = styles.table("boxes", 2, cam.box_height, cam.box_color, torch.zeros(1))
    assert table.tolist() == [[cam.box_height, 1, 2, 3], [cam.box_height, *cam.box_color]]
    _, rgb = camera_image(torch.zeros(1, 3), world, cam, styles=styles)
    row = cam.n_rows // 2  # looks straight ahead: meets the box at the camera's height
    assert (rgb[0, row, 1].to(torch.float32) - torch.tensor((1, 2, 3)) / (1 + 0.08 * 1.9)).abs().max() <= 1


@pytest.mark.parametrize("bad, key", [
    ({"height": 0.0}, "boxes[0].height"), ({"height": "tall"}, "boxes[0].height"),
    ({"color": [1, 2]}, "boxes[0].color"), ({"color": [0, 300, 0]}, "boxes[0].color"), ({"color": [0.5, 1, 2]}, "boxes[0].color"),
    ({"colour": [1, 2, 3]}, "colour"),
])
def test_map_rejects_bad_styles(bad, key):
    with pytest.raises(MapError, match=key.replace("[", r"\[").replace("]", r"\]")):
        parse_map({"size": [10.0, 10.0], "boxes": [{"center": [2.0, 0.0], "size": [0.2, 1.0], **bad}]})
    with pytest.raises(MapError, match="circles"):
        parse_map({"size": [10.0, 10.0], "circles": [{"center": [2.0, 0.0], "radius": 0.2, "color": "red"}]})


def test_recorded_camera_images_use_the_map_styles(tmp_path):
    """A room walled by green boxes: every column of the recorded image's middle row is green."""
    import base64

    import numpy as np
    from mcap.reader import make_reader

    from torchnav.envs import make_nav_env
    from torchnav.record import EpisodeRecorder, JsonDecoderFactory, record_rollout

    style = "height: 1.0, color: [0, 255, 0]"
    path = tmp_path / "green.yaml"
    path.write_text(f"""
size: [6.0, 6.0]
boxes:
  - {{center: [0.0, -2.8], size: [6.0, 0.4], {style}}}
  - {{center: [0.0, 2.8], size: [6.0, 0.4], {style}}}
  - {{center: [-2.8, 0.0], size: [0.4, 5.2], {style}}}
  - {{center: [2.8, 0.0], size: [0.4, 5.2], {style}}}
""")
    env = make_nav_env(str(path), num_envs=2, max_steps=20, camera={"enabled": True, "n_cols": 16, "n_rows": 9})
    out = tmp_path / "green.mcap"
    with EpisodeRecorder(out, env, envs=(0,)) as rec:
        record_rollout(env, None, 3, rec)
    images = []
    with open(out, "rb") as f:
        for _, channel, _, msg in make_reader(f, decoder_factories=[JsonDecoderFactory()]).iter_decoded_messages():
            if channel.topic == "/env0/camera":
                images.append(np.frombuffer(base64.b64decode(msg["data"]), dtype=np.uint8).reshape(9, 16, 3))
    assert images
    for img in images:
        mid = img[4].astype(int)
        assert (mid[:, 0] == 0).all() and (mid[:, 2] == 0).all() and (mid[:, 1] > 0).all()
