"""Face tracking: RGB frames in, speaker face states and viewer poses out (pure; no devices).

* :mod:`~holo_viewer.tracking.landmarks`: face boxes + 68 landmarks (dlib; the ``[live]`` extra)
* :mod:`~holo_viewer.tracking.head_model`: the landmarks embedded on the project's own head,
  projected as a function of AU state, jaw, head rotation and position
* :mod:`~holo_viewer.tracking.fit`: regularised Gauss-Newton fit of that model to one frame
* :mod:`~holo_viewer.tracking.filters`: One-Euro smoothing and its measured lag
* :mod:`~holo_viewer.tracking.tracker`: :class:`FaceTracker`, frame -> :class:`TrackedFrame`
* :mod:`~holo_viewer.tracking.viewer`: webcam face position -> viewer angle and distance
* :mod:`~holo_viewer.tracking.video`: a video file -> ``speaker.npz`` that ``react`` reads

Submodules are imported on use (dlib is optional).
"""

from __future__ import annotations

__all__ = ["landmarks", "head_model", "fit", "filters", "tracker", "viewer", "video"]
