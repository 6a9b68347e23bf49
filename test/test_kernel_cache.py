"""The package's numba cache is dropped when a kernel source changes (``tensegrity_sim/_kernel_cache.py``):
numba itself checks a cached kernel against its own file only."""
import time

from tensegrity_sim import _kernel_cache


def _package(tmp_path):
    """A package tree with two kernel modules, a plain module and cached kernels of both."""
    (tmp_path / "methods" / "__pycache__").mkdir(parents=True)
    (tmp_path / "methods" / "_a_kernels.py").write_text("def a(): return 1\n")
    (tmp_path / "methods" / "_b_kernels.py").write_text("def b(): return a()\n")
    (tmp_path / "plain.py").write_text("x = 1\n")
    cached = [tmp_path / "methods" / "__pycache__" / name for name in ("_b_kernels.b-1.py311.nbi",
                                                                      "_b_kernels.b-1.py311.1.nbc")]
    for path in cached:
        path.write_bytes(b"compiled")
    return cached


def test_a_changed_kernel_source_drops_every_cached_kernel(tmp_path):
    cached = _package(tmp_path)
    assert _kernel_cache.drop_stale(tmp_path)          # no stamp yet: dropped, stamped
    assert not any(path.exists() for path in cached)
    stamp = tmp_path / "__pycache__" / _kernel_cache.STAMP
    assert stamp.read_text() == _kernel_cache.sources_digest(tmp_path)
    for path in cached:                                   # compiled again by numba
        path.write_bytes(b"compiled")
    assert not _kernel_cache.drop_stale(tmp_path)      # nothing changed: kept
    (tmp_path / "plain.py").write_text("x = 2\n")
    assert not _kernel_cache.drop_stale(tmp_path)      # not a kernel source: kept
    assert all(path.exists() for path in cached)
    # the callee's file changes, the caller's cache (another file) must go
    (tmp_path / "methods" / "_a_kernels.py").write_text("def a(): return 2\n")
    assert _kernel_cache.drop_stale(tmp_path)
    assert not any(path.exists() for path in cached)


def test_the_package_is_stamped_with_its_kernel_sources():
    """Importing the package stamped its cache with the digest of its own kernel sources."""
    stamp = _kernel_cache.PACKAGE / "__pycache__" / _kernel_cache.STAMP
    assert stamp.read_text() == _kernel_cache.sources_digest()
    package = _kernel_cache.PACKAGE
    names = {path.relative_to(package).as_posix() for path in _kernel_cache._sources(package)}
    assert {"methods/qp/_qp_kernels.py", "methods/qp/_daqp_kernels.py", "methods/inextensible/_kernels.py",
            "methods/elastic/_kernels.py", "methods/contact/_detection_kernels.py", "methods/_c_calls.py",
            "_system_kernels.py", "ros/_publication_kernels.py"} <= names


def _fresh_kernel():
    """A numba kernel never compiled before in this process (nor cached: ``cache`` off)."""
    import numba

    @numba.njit(cache=False)
    def kernel(x):
        total = 0.0
        for k in range(x.shape[0]):
            total += x[k] * x[k]
        return total

    return kernel


def test_the_compile_clock_counts_compiling_and_only_while_entered():
    import numpy as np

    x = np.arange(4.0)
    outside = _fresh_kernel()
    with _kernel_cache.CompileClock() as clock:
        assert clock.seconds == clock.compiling == 0.0
        kernel = _fresh_kernel()
        start = time.perf_counter()
        assert kernel(x) == 14.0          # compiles now
        took = time.perf_counter() - start
        assert 0.0 < clock.compiling <= clock.seconds <= took
        assert clock.seconds > 0.5 * took  # the call's time is the compiling, nearly all of it
        before = clock.seconds
        assert kernel(x) == 14.0           # compiled: nothing more counted
        assert clock.seconds == before
    assert outside(x) == 14.0              # compiled after the clock was left: not counted
    assert clock.seconds == before


def test_simulate_takes_the_kernels_readied_while_stepping_out_of_the_wall_time():
    """A kernel compiled inside the run (here by the per-step callback) counts as compile time, and the
    stepping's wall time is the run's time without it."""
    import numpy as np

    import tensegrity_sim as ts
    from tensegrity_sim.cli import simulate

    sim = ts.Simulator(ts.load_scene("prism3"), method="elastic", dt=1e-3)
    sim.step()   # the stepping kernels ready before the clock
    kernel, x = _fresh_kernel(), np.arange(3.0)
    calls = []

    def on_step(_):
        if not calls:
            calls.append(kernel(x))
    with _kernel_cache.CompileClock() as clock:
        start = time.perf_counter()
        summary = simulate(sim, 20, on_step=on_step, clock=clock)
        total = time.perf_counter() - start
    assert calls == [5.0] and summary.compiled and summary.compile_time == clock.seconds > 0.0
    assert summary.wall_time <= total - clock.compiling
    assert summary.wall_time >= 0.0
    assert "compiling kernels (first run only): " in "\n".join(summary.lines())
