"""Depth of many inputs: captures, image sequences and videos, each written to its own files.

What a long job needs, for ``prismstereo depth`` and for Python callers:

* :func:`plan` names every output before any work (``<stem>.<format>`` per capture, ``<stem>_000000.<format>``, ...
  per sequence frame), refuses collisions and outputs that would overwrite an input, and with ``skip_existing``
  marks what an earlier run already wrote (a sequence resumes at its first missing frame).
* :class:`Runner` computes and writes in a pipeline: the next captures or frames are decoded on a reader thread and
  the finished ones written on a writer thread (bounded queues, outputs in input order) while the model runs. Every
  file is written under a temporary name and renamed into place (:func:`~prismstereo.io.replacing`), so a failed
  write or a stopped job leaves whole files only.
* :func:`run` goes through the tasks with one progress bar, in this process or spread over worker processes (each
  with its own torch threads and onnxruntime session; forked on Linux, so the model is built once), reports each
  failing input and goes on with the others; or on a Ray cluster (:mod:`prismstereo.jobs.distributed`, where
  :class:`~prismstereo.jobs.distributed.DepthPredictor` also maps the model over a Ray Dataset).

Example:
    >>> tasks = plan(["capture.png"], Path("out"), WriteOptions())
    >>> tasks[0].outputs[0].depth
    PosixPath('out/capture.npy')
"""

from prismstereo.jobs.plan import Outputs, Selection, Task, WriteOptions, plan
from prismstereo.jobs.run import JobSummary, run
from prismstereo.jobs.runner import BACKENDS, Runner, TaskReport

__all__ = ["Outputs", "WriteOptions", "Selection", "Task", "TaskReport", "JobSummary", "Runner", "plan", "run",
           "BACKENDS"]
