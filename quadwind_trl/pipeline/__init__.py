"""The reproduction pipeline's stage graph and what its executors share.

:class:`Stage` is one recipe command, the output that marks it done, the stages whose outputs it
reads and the resources it asks a scheduler for. A recipe (``recipes/reproduce.py``) builds the
graph and runs it (:func:`~quadwind_trl.pipeline.run.run_plan`) with one of two executors:
:mod:`~quadwind_trl.pipeline.local` (each stage a process of this machine, ``--jobs`` at a time;
the default, which imports no Ray) or :mod:`~quadwind_trl.pipeline.ray_executor` (``--executor
ray``: each stage a Ray task, on one machine or a cluster). Both skip the stages whose output
exists, run the ``after`` step of a stage in the driving process, and add each finished stage's
wall time, node and load to the same ``pipeline_times.json`` (:func:`record_time`), from which
:func:`longest_chain` gives the time a reproduction takes on enough nodes.
"""
from .stages import Chain, Stage, StageResources, check_all_ran, is_done, is_forced, longest_chain, record_time, stage_needs

__all__ = ["Chain", "Stage", "StageResources", "check_all_ran", "is_done", "is_forced", "longest_chain", "record_time",
           "stage_needs"]
