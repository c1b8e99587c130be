"""Frames in, depth out: videos, folders and globs of captures read frame by frame (:mod:`prismstereo.stream.video`)
and :class:`DepthStream`, one model's depth of frames pushed one at a time with the temporal prior
(:mod:`prismstereo.stream.depth_stream`)."""

from prismstereo.stream.depth_stream import DepthStream, StreamResult

__all__ = ["DepthStream", "StreamResult"]
