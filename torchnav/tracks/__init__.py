"""Line-following tracks: YAML polylines or PNG masks -> centreline segments and a lap path.

    from torchnav.tracks import load_track
    track = load_track("course")          # shipped: course, loop, oval (available_tracks())
    tt = track.tensors(reach=0.06)        # on a device: sensor grid, lap path, arc lengths

See docs/line.md for the file format.
"""

from ..maps.occupancy import read_mask
from .geometry import catmull_rom, fillet_polyline, path_pose, project_on_path, resample, wrap_delta
from .loader import available_tracks, load_track, parse_track
from .png import skeletonize, track_from_mask
from .track import Track, TrackError, TrackTensors

__all__ = [
    "Track", "TrackTensors", "TrackError", "load_track", "parse_track", "available_tracks", "track_from_mask",
    "read_mask", "skeletonize", "project_on_path", "path_pose", "wrap_delta", "fillet_polyline", "catmull_rom", "resample",
]
