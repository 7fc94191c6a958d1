"""Signals at many points of real runs: each must end the run within seconds and mark it failed.

``python scripts/signal_stress.py [--tries N] [--seed S] [--cases CASE ...]`` starts real runs of the command, each in its own
session (so that SIGINT can go to the whole process group, as Ctrl-C in a terminal sends it), and sends a signal:

* ``toy``: ``hbni_toy`` with an empty numba cache, the signal from 0.2 to 20 s after the start: the imports, the
  config, numba compiling or loading the kernels, Pyro's sampler;
* ``compile``: the same, the signal sent from inside the callback numba's compiler makes into Python (whose
  exceptions C code ignores: tests/adversarial/stop_while_compiling.py);
* ``sampler``: ``hbni_toy`` with a warm numba cache, the signal 0.5 to 4 s after the run started (status running);
* ``planner``: ``package_delivery`` with a warm cache, 1 to 8 s after the run started;
* ``sweep``: a two-job ``hbni_toy`` sweep (joblib workers) with an empty cache, 0 to 15 s after its first job
  started (the workers compile, then sample), the signal to the sweep's parent.

It alternates SIGINT to the process group, SIGTERM and SIGHUP to the command, and ``python -m experiments.run``
with the ``hbni-pyro`` console script. A try passes when every process of the session has ended within
:data:`HANG_S` seconds of the signal, the command died by that signal, each run folder that exists says
``failed`` with the signal named (or ``completed``, for a run that finished before the signal), and no lock file
is left. It prints one line per try, then the counts; the exit status is 1 if any try failed.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from hbni_infra.streams import numpy_generator

ROOT = Path(__file__).resolve().parents[1]
HANG_S = 15.0
"""A process of the run still alive this long after the signal is a hang."""
SLOW = ["hbni.fit.num_chains=2", "hbni.fit.num_samples=1000000", "hbni.fit.warmup_steps=10", "progress=false"]
PLANNER = ["experiment=package_delivery", "progress=false"]
SIGNALS = [("SIGINT", True), ("SIGTERM", False), ("SIGHUP", False)]  # (signal, to the whole process group)


def session(pid: int) -> list[int]:
    """The live processes of session ``pid`` (Linux /proc)."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if fields[0] not in ("Z", "X") and int(fields[3]) == pid:
            out.append(int(stat.parent.name))
    return out


def command_line(pid: int) -> str:
    """The command line of process ``pid`` (``"?"`` when it is gone)."""
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace").strip()[:200]
    except OSError:
        return "?"


def statuses(folder: Path) -> dict[str, dict | None]:
    """``status.json`` of the run folder ``folder`` or of each job of a sweep folder (``None``: unreadable)."""
    found = {}
    for path in [folder / "status.json", *sorted(folder.glob("*/status.json"))]:
        if path.is_file():
            try:
                found[str(path.parent.relative_to(folder))] = json.loads(path.read_text())
            except (OSError, ValueError):
                found[str(path.parent.relative_to(folder))] = None
    return found


def one_try(case: str, signame: str, group: bool, delay: float, script: bool, work: Path) -> dict:
    """Start one run, signal it, and judge how it ended."""
    folder = work / "run"
    env = dict(os.environ, NUMBA_CACHE_DIR=str(work / "numba"), HBNI_PYRO_ROOT=str(work))
    if case in ("sampler", "planner"):
        env["NUMBA_CACHE_DIR"] = str(Path(tempfile.gettempdir()) / "signal-stress-warm-numba")
    command = [str(Path(sys.executable).parent / "hbni-pyro")] if script else [sys.executable, "-m", "experiments.run"]
    args = PLANNER if case == "planner" else ["experiment=hbni_toy", *SLOW]
    if case == "sweep":
        args = ["-m", *args, "seed=0,1", f"hydra.sweep.dir={folder}", "hydra.launcher.n_jobs=2"]
    else:
        args = [*args, f"hydra.run.dir={folder}"]
    if case == "compile":
        command = [sys.executable, str(ROOT / "tests" / "adversarial" / "stop_while_compiling.py")]
        env.update(STOP_SIGNAL=signame, STOP_RUN_DIR=str(folder))
    proc = subprocess.Popen(
        [*command, *args],
        cwd=work,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    start = time.monotonic()
    signum = getattr(signal, signame)
    if case in ("sampler", "planner"):  # the delay counts from the run's start
        while (statuses(folder).get(".") or {}).get("status") != "running" and proc.poll() is None:
            time.sleep(0.05)
    if case == "sweep":  # from its first job's start
        while not statuses(folder) and proc.poll() is None:
            time.sleep(0.05)
    if case != "compile":
        time.sleep(max(0.0, delay - (time.monotonic() - start) if case == "toy" else delay))
        sent_at = time.monotonic() - start
        kernels = len(list(Path(env["NUMBA_CACHE_DIR"]).rglob("*.nbi")))
        started = bool(statuses(folder))
        if proc.poll() is None:
            (os.killpg if group else os.kill)(proc.pid, signum)
    else:
        sent_at, kernels, started = float("nan"), 0, True
    signalled = time.monotonic()
    hang_at = signalled + (HANG_S if case != "compile" else 120.0 + HANG_S)
    ended_s = None  # when the session was last seen to empty; it must stay empty for a second
    while time.monotonic() < hang_at:
        if session(proc.pid):
            ended_s = None
        elif ended_s is None:
            ended_s = time.monotonic() - signalled
        elif time.monotonic() - signalled - ended_s >= 1.0:
            break
        time.sleep(0.05)
    left = session(proc.pid)
    ended_s = time.monotonic() - signalled if left or ended_s is None else ended_s
    commands = [command_line(pid) for pid in left]
    for pid in left:
        os.kill(pid, signal.SIGKILL)
    stderr = proc.communicate()[1]
    found = statuses(folder)
    locks = [str(p.relative_to(work)) for p in work.rglob("*.lock")]
    problems = []
    if left:
        problems.append(f"hang: {len(left)} processes alive {HANG_S:g} s after the signal: {commands}")
    if proc.returncode != -signum and not left:
        problems.append(f"exit status {proc.returncode}, expected death by {signame}")
    for job, entry in found.items():
        state = None if entry is None else entry.get("status")
        if state == "completed":
            continue
        if state != "failed" or "stopped by SIG" not in entry.get("error", ""):
            problems.append(f"status of {job}: {entry}")
    if locks:
        problems.append(f"lock files left: {locks}")
    phase = (
        "in the compiler's callback"
        if case == "compile"
        else "before the run"
        if not started
        else (f"during the run, {kernels} kernels in the numba cache")
    )
    return {
        "phase": phase,
        "case": case,
        "signal": signame + (" (group)" if group else ""),
        "entry": "hbni-pyro" if script else "python -m",
        "sent_s": round(sent_at, 2),
        "ended_s": round(ended_s, 2),
        "statuses": {k: (v or {}).get("status") for k, v in found.items()},
        "problems": problems,
        "stderr": stderr.strip().splitlines()[-(30 if problems else 1) :],
    }


def warm_up() -> None:
    """Compile the kernels once into the warm cache that the sampler and planner tries use."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(Path(tempfile.gettempdir()) / "signal-stress-warm-numba"))
    for part in ("package_delivery", "others"):
        script = ROOT / "tests" / "compile_kernels.py"
        subprocess.run([sys.executable, "-P", str(script), part], cwd=ROOT, env=env, check=True, capture_output=True)


def schedule(tries: int, rng: np.random.Generator, only: list[str] | None = None) -> list[tuple[str, float]]:
    """``(case, delay)`` for each try: 60 % ``toy``, then ``sweep``, ``sampler``, ``planner`` and ``compile`` (or the
    cases ``only``, in equal shares)."""
    shares = [("toy", 0.6), ("sweep", 0.15), ("sampler", 0.1), ("planner", 0.1), ("compile", 0.05)]
    if only:
        shares = [(case, 1 / len(only)) for case in only]
    cases = [case for case, share in shares for _ in range(max(1, round(share * tries)))][:tries]
    cases += [shares[0][0]] * (tries - len(cases))
    delays = {"toy": (0.2, 20.0), "sweep": (0.0, 15.0), "sampler": (0.5, 4.0), "planner": (1.0, 8.0), "compile": (0, 0)}
    return [(case, rng.uniform(*delays[case])) for case in cases]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tries", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0)
    cases = ["toy", "sweep", "sampler", "planner", "compile"]
    parser.add_argument("--cases", nargs="+", choices=cases, help="only these cases, in equal shares (default: all)")
    args = parser.parse_args()
    for signame, _ in SIGNALS:  # a signal ignored here (a background job's SIGINT) would be ignored by the runs too
        if signal.getsignal(getattr(signal, signame)) == signal.SIG_IGN:
            signal.signal(getattr(signal, signame), signal.SIG_DFL)
    rng = numpy_generator(args.seed)
    warm_up()
    results = []
    for k, (case, delay) in enumerate(schedule(args.tries, rng, args.cases)):
        signame, group = SIGNALS[k % len(SIGNALS)]
        with tempfile.TemporaryDirectory(prefix="signal-stress-") as work:
            result = one_try(case, signame, group, delay, script=k % 2 == 1, work=Path(work))
        results.append(result)
        verdict = "ok" if not result["problems"] else "FAIL: " + "; ".join(result["problems"])
        if result["problems"]:  # what the command said
            verdict += "".join(f"\n    | {line}" for line in result["stderr"])
        print(
            f"{k:2d} {case:8s} {result['signal']:16s} {result['entry']:10s} sent at {result['sent_s']:6.2f} s, "
            f"({result['phase']}), ended {result['ended_s']:5.2f} s later, status "
            f"{result['statuses'] or 'no run folder'}: {verdict}",
            flush=True,
        )
    hangs = sum(any(p.startswith("hang") for p in r["problems"]) for r in results)
    failed = sum(bool(r["problems"]) for r in results)
    slowest = max(r["ended_s"] for r in results)
    print(
        f"{len(results)} tries: {len(results) - failed} ok, {failed} failed, {hangs} hangs; slowest end {slowest:.2f} s"
    )
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
