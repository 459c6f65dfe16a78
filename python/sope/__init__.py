"""sope: structured-light scanning, object recognition and pose estimation.

Thin bindings over the C++ library (see README "From Python"). Arrays returned are numpy
views of the C++ buffers; long calls release the GIL.
"""
from ._sope import (  # noqa: F401
    Database,
    Error,
    FrameSet,
    Recogniser,
    decode,
    default_rig,
    load_calibration,
    load_cloud,
    load_frame_set,
    save_calibration,
    save_cloud,
    save_frame_set,
    simulate,
    triangulate,
)
