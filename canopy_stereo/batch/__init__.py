"""Batch phenotyping: many raw stereo bags -> one tidy trait table, on Dask distributed.

* :mod:`~canopy_stereo.batch.work`: one bag -> one row (the core of
  ``reconstruct --measure`` on every stereo pair, medians over the frames).
* :mod:`~canopy_stereo.batch.frames`: stereo pairs of a bag, decoded without ROS.
* :mod:`~canopy_stereo.batch.table`: ``plants.csv`` / ``plants.parquet`` / ``errors.csv``.
* :mod:`~canopy_stereo.batch.engine`: :func:`run_batch` on a LocalCluster or a cluster.
* :mod:`~canopy_stereo.batch.plots`: per-plant plots of each trait over the dates.

Pure Python over the core: nothing here imports rclpy (workers need only the core
and ``dask[distributed]``). The command is ``canopy-stereo batch``.
"""
from canopy_stereo.batch.work import TRAITS, BatchOptions, measure_frame, process_bag

__all__ = ["TRAITS", "BatchOptions", "measure_frame", "process_bag", "run_batch"]


def run_batch(*args, **kwargs):
    """See :func:`canopy_stereo.batch.engine.run_batch` (imported lazily: Dask is optional)."""
    from canopy_stereo.batch.engine import run_batch as _run

    return _run(*args, **kwargs)
