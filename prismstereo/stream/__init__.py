"""Frames in, depth out: videos, folders and globs of captures read frame by frame (:mod:`prismstereo.stream.video`)
and :class:`DepthStream`, one model's depth of frames pushed one at a time with the temporal prior
(:mod:`prismstereo.stream.depth_stream`; without torch, on numpy frames: :class:`FrameStream`,
:mod:`prismstereo.stream.frame_stream`). The names are imported on first use: the frame stream imports no torch.
"""

from prismstereo.lazy import lazy_names

__all__ = ["DepthStream", "FrameStream", "StreamResult"]

_LAZY = {"DepthStream": "prismstereo.stream.depth_stream", "FrameStream": "prismstereo.stream.frame_stream",
         "StreamResult": "prismstereo.stream.frame_stream"}

__getattr__, __dir__ = lazy_names(__name__, _LAZY, __all__)
