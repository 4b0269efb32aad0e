"""Batch rendering: many clips to hologram videos, resumable, in-process or on Ray.

``holo-viewer render-batch MANIFEST --out DIR`` is a thin front for :func:`run_batch`:

* :mod:`.manifest` reads and validates the manifest (JSON Lines or CSV, one job per row) and
  fingerprints each job's content (:func:`job_hash`);
* :mod:`.jobs` resolves a job's face sequence (once, in the driver) and splits it into chunks;
* :mod:`.worker` renders a chunk through the pipeline and encodes it (no files written there);
* :mod:`.video` encodes MPEG-TS segments and joins them into one mp4 without re-encoding;
* :mod:`.executors` runs chunks in this process or as Ray tasks (the ``cluster`` extra);
* :mod:`.runner` ties it together: resume, atomic outputs named by hash, ``summary.json``.

See docs/batch.md. Importing this package does not import Ray, torch or the renderer.
"""

from .executors import InProcessExecutor, RayExecutor, make_executor
from .jobs import plan_chunks
from .manifest import JobSpec, RowError, job_hash, read_manifest
from .runner import BatchSummary, JobRecord, run_batch

__all__ = ["run_batch", "BatchSummary", "JobRecord", "read_manifest", "JobSpec", "RowError", "job_hash",
           "plan_chunks", "InProcessExecutor", "RayExecutor", "make_executor"]
