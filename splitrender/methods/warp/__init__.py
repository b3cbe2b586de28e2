"""``warp``: client/server depth-image warping (Smit et al., "An image-warping
architecture for VR"), which is also the MeshWarp (MW) baseline of SAS and QUASAR.

Server half: renders colour, depth and per-pixel object IDs for one or two
**reference views** per frame (the second placed by ``second_view``: a wider
stereo-like pair, a step back, or a step along the predicted motion), with an
enlarged field of view (``fov_scale``, image-plane scale as ``atw``'s overscan)
and a resolution scale.  Colour goes as lossy video; depth as 16-bit inverse-depth
codes (``splitrender.codecs.depth``), either lossless (two 8-bit planes in one
lossless HEVC 4:0:0 picture) or BC4-like 8x8 blocks + zstd in the metadata.  The
per-pixel object IDs and the model matrices of the visible objects (at the frame's
time and one server frame earlier, for motion extrapolation) go in the metadata.

Client half: per object one 4x4 warp matrix
``M_i = P_cur V_cur O_i(t) O_i(ref)^-1 V_ref^-1`` (the paper's chain; the reference
projection's inverse is applied analytically in the shader because depth arrives in
metres); ``O_i(t)`` is extrapolated from the two model matrices (slerp on rotation,
linear on translation).  The grid of reference pixels is drawn as Jacobian-sized point
splats, Jacobian quad splats (geometry shader), or a grid mesh (its outer vertices on the
image border, so it spans the whole reference image) cut at depth and
moving-object discontinuities.  The view nearest the display pose is drawn first; a
second view only fills the pixels it left uncovered (``view_merge``; the paper's plain
depth test is ``"depth"``).  Pixels no warped fragment reaches are holes; they are
filled by scanning along the epipolar direction both ways and taking the farther
sample, and the hole mask (before filling) is returned for the metrics.
"""

from __future__ import annotations

from ..base import MethodSpec, register_method
from .config import (MAX_COORD_M, MAX_OBJECT_ID, META_VERSION, SHADERS, DepthCoding, Reconstruction, SecondView, ViewMerge,
                     WarpConfig, fov_scale_for, reference_intrinsics, reference_poses)
from .wire import ReferenceFrame, ReferenceView, WarpMetaError, parse_update  # the shared wire format

SPEC = register_method(MethodSpec("warp", "splitrender.methods.warp.server:WarpServer",
                                  "splitrender.methods.warp.client:WarpClient", WarpConfig,
                                  "depth-image warping (MeshWarp): points, quads or mesh"))


def __getattr__(attr: str) -> object:
    """The halves (and the client's helpers), loaded on first use: importing the client never imports the server."""
    if attr == "WarpServer":
        from .server import WarpServer

        return WarpServer
    if attr in ("WarpClient", "extrapolate_model", "warp_matrices", "mesh_grid_indices"):
        from . import client

        return getattr(client, attr)
    raise AttributeError(f"module {__name__!r} has no attribute {attr!r}")


__all__ = ["MAX_COORD_M", "MAX_OBJECT_ID", "META_VERSION", "SHADERS", "SPEC", "DepthCoding", "Reconstruction", "ReferenceFrame",
           "ReferenceView", "SecondView", "ViewMerge", "WarpClient", "WarpConfig", "WarpMetaError", "WarpServer",
           "extrapolate_model", "fov_scale_for", "mesh_grid_indices", "parse_update", "reference_intrinsics",
           "reference_poses", "warp_matrices"]
