"""Infrastructure shared by ``hbni_pyro``, ``classifiers``, ``decpomdp`` and ``experiments``.

A leaf package: it imports nothing of the project and holds no domain code.

* :mod:`hbni_infra.files`: atomic, fsynced file writes that respect the umask (and whole directories: ``atomic_path``).
* :mod:`hbni_infra.tensorfile`: one-file storage of named tensors plus JSON metadata (safetensors, no pickle).
* :mod:`hbni_infra.fingerprint`: what produced a checkpoint or cache, and a check that names the field that differs.
* :mod:`hbni_infra.counter_random`: counter-based SplitMix64 random streams for compiled (numba) loops.
* :mod:`hbni_infra.stats`: the exact binomial test, the Wilson interval and the two-sample Kolmogorov-Smirnov test
  (scipy's) and a two-sample z test.
* :mod:`hbni_infra.threads`: one thread setting for torch's intra-op threads and compiled loops' worker threads.
* :mod:`hbni_infra.ros`: ROS plumbing: the ``ros`` extra imported on first use, ROS times, camera images to and from
  ROS messages.

See ``docs/architecture.md`` for where this sits in the project.
"""

from hbni_infra.files import atomic_write_bytes, atomic_write_text
from hbni_infra.fingerprint import check_fingerprint, digest
from hbni_infra.tensorfile import load_tensors, save_tensors, seal
from hbni_infra.version import __version__
from hbni_infra.threads import set_threads, single_thread, threads, torch_threads, worker_threads

__all__ = [
    "__version__",
    "atomic_write_bytes",
    "atomic_write_text",
    "check_fingerprint",
    "digest",
    "load_tensors",
    "save_tensors",
    "seal",
    "set_threads",
    "single_thread",
    "threads",
    "torch_threads",
    "worker_threads",
]
