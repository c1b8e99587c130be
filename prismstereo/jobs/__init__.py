"""Depth of many inputs: captures, image sequences and videos, each written to its own files.

What a long job needs, for ``prismstereo depth`` and for Python callers, by responsibility:

* the plan (:func:`plan`, :mod:`~prismstereo.jobs.plan`): every output named before any work (``<stem>.<format>``
  per capture or image of a sequence, ``<stem>_000000.<format>``, ... per video frame), collisions and outputs that
  would overwrite an input refused, and with ``skip_existing`` what an earlier run already wrote marked (a sequence
  resumes at its first missing frame). Pure: it reads no image and writes nothing; its errors (:class:`PlanError`)
  name its arguments, which the CLI names by its flags. :func:`check_inputs` then reads each input's first image
  before any model is built (a capture that does not decode or is of another size fails in a second, not after the
  build).
* the pipeline (:class:`Pipeline`, :mod:`~prismstereo.jobs.pipeline`): one process's
  :class:`~prismstereo.predictor.Predictor` and writers; the next captures or frames are decoded on a reader thread
  and the finished ones written on a writer thread (bounded queues, outputs in input order) while the model runs.
  Every file is written under a temporary name and renamed into place (:func:`~prismstereo.io.replacing`), so a
  failed write or a stopped job leaves whole files only.
* the executors (:mod:`~prismstereo.jobs.executors`, one interface): this process (:class:`InProcess`), worker
  processes (:class:`WorkerProcesses`, each with its share of the cores and its own sessions) or Ray actors
  (:class:`~prismstereo.jobs.ray_executor.RayCluster`, where :class:`~prismstereo.jobs.ray_executor.DepthMapper`
  also maps the predictor over a Ray Dataset); :func:`run` goes through the tasks on one of them with one progress
  bar, reports each failing input and goes on with the others.

The plan, its checks and the run import without torch (a host that only runs cached graphs plans its outputs too);
the executors and the pipeline, which run models, are imported on first use.

Example:
    >>> tasks = plan(["capture.png"], Path("out"), WriteOptions())
    >>> tasks[0].outputs[0].depth
    PosixPath('out/capture.npy')
"""

# the plan and run import without torch, and eagerly: ``plan`` and ``run`` name both a function and its module, and a
# lazily imported module would take the function's place
from prismstereo.jobs.plan import Outputs, PlanError, Selection, Task, TaskReport, WriteOptions, check_inputs, plan
from prismstereo.jobs.run import JobSummary, run
from prismstereo.lazy import lazy_names

__all__ = ["Executor", "InProcess", "JobSummary", "Outputs", "Pipeline", "PlanError", "Selection", "Task",
           "TaskReport", "WorkerProcesses", "WriteOptions", "check_inputs", "plan", "run"]

_LAZY = {"Executor": "prismstereo.jobs.executors", "InProcess": "prismstereo.jobs.executors",
         "WorkerProcesses": "prismstereo.jobs.executors", "Pipeline": "prismstereo.jobs.pipeline"}


__getattr__, __dir__ = lazy_names(__name__, _LAZY, __all__)
