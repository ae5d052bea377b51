"""Maps: YAML files describing static worlds, turned into batched ``World`` tensors.

>>> from torchnav.maps import load_map
>>> spec = load_map("arena")            # a shipped map, or a path to your own .yaml
>>> world = spec.build_world(batch_size=64, device="cpu")

See ``docs/maps.md`` for the file format and the shipped maps.
"""

from .loader import available_maps, load_map, parse_map
from .spec import MapError, MapSpec, RandomBoxes, RandomCircles, RandomMovers

__all__ = [
    "MapError",
    "MapSpec",
    "RandomBoxes",
    "RandomCircles",
    "RandomMovers",
    "available_maps",
    "load_map",
    "parse_map",
]
