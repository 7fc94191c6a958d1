"""The compiled-code cache directory follows every source that compiled code inlines."""

import numba

from hbni_infra import numba_cache


def _tree(root, random_source: str, loop_source: str):
    (root / "hbni_infra").mkdir(parents=True, exist_ok=True)
    (root / "decpomdp" / "engine").mkdir(parents=True, exist_ok=True)
    (root / "hbni_infra" / "counter_random.py").write_text(random_source)
    (root / "decpomdp" / "engine" / "loop.py").write_text(loop_source)
    return root


def test_a_changed_inlined_source_moves_the_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))
    root = _tree(tmp_path / "src", "a = 1\n", "b = 1\n")
    first = numba_cache.cache_dir(root)
    assert first == numba_cache.cache_dir(root) and first.is_dir() and first.parent == tmp_path / "cache"
    _tree(root, "a = 2\n", "b = 1\n")  # the random streams changed: every kernel inlining them is stale
    second = numba_cache.cache_dir(root)
    _tree(root, "a = 2\n", "b = 2\n")  # the event loop changed
    assert len({first, second, numba_cache.cache_dir(root)}) == 3


def test_the_package_points_numba_at_its_cache():
    import decpomdp.engine  # noqa: F401
    import hbni_pyro.mcmc.class_move_numba  # noqa: F401

    assert numba.config.CACHE_DIR == str(numba_cache.use_cache_dir()) == str(numba_cache.cache_dir())
