"""Several runs trained at once in one process: the jobs of a sweep with ``train.together=true``.

``python -m disent -m seed=0,1,2 train.together=true`` sets up each job in turn, as Hydra launches it, in its own
folder with its own config, seed and lock (:func:`queue_run`: the same seeded initialisation as the run alone); when
the sweep has launched them all, :func:`train_queued` trains them side by side, one thread each, each on its own
CUDA stream on a GPU, so that one card runs the small kernels of several models at once, then evaluates each into
its ``eval.json``.  A training step draws no random numbers, so each run's numbers are the ones it trains to alone
(``tests/test_launchers.py`` checks this on two tiny runs).  With ``train.stack=true`` runs that differ only in
their seed train as one stacked model instead (:mod:`disent.stack`), equal to alone to float rounding.  Only
Hydra's basic launcher runs a sweep's jobs in this process: another launcher would set the jobs up in processes
that never train them, so it is refused.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from contextlib import nullcontext
from pathlib import Path

import torch

from disent.config import ConfigError, check_config
from disent.storage import RunLock
from disent.train import finish, set_up, train_loop

QUEUED: list = []  # (Training, RunLock) of each job set up and waiting for the sweep's end
BASIC_LAUNCHER = "hydra._internal.core_plugins.basic_launcher.BasicLauncher"


def queue_run(cfg, run_dir, launcher: str) -> None:
    """Check and set up the run of ``cfg`` in ``run_dir`` (holding its lock), to be trained by :func:`train_queued`."""
    if launcher != BASIC_LAUNCHER:
        raise ConfigError(
            f"train.together=true trains a sweep's jobs in one process, which only Hydra's basic launcher runs them in "
            f"(not {launcher.rsplit('.', 1)[-1]}); leave hydra/launcher at its default"
        )
    check_config(cfg)
    lock = RunLock(run_dir).acquire()
    try:
        QUEUED.append((set_up(cfg, Path(run_dir)), lock))
    except BaseException:
        lock.release()
        raise
    print(f"set up {run_dir}; trained with the sweep's other jobs once all are set up")


def train_one(s) -> dict:
    """One queued run from where it stands to its ``eval.json``, on its own CUDA stream on a GPU."""
    torch.set_num_threads(s.cfg.train.threads or torch.get_num_threads())  # this thread's own count (see Prefetcher)
    stream = torch.cuda.Stream(s.device) if s.device.type == "cuda" else None
    with torch.cuda.stream(stream) if stream is not None else nullcontext():
        stopped, batch = train_loop(s)
        return finish(s, stopped, batch)


def train_queued() -> list[tuple[Path, dict | BaseException]]:
    """Train every queued run side by side (or stacked: ``train.stack``), then empty the queue; ``(run folder, eval
    metrics or the error that stopped it)`` per run, in the order they were set up.  Side by side, one run's failure
    stops only that run."""
    queued = QUEUED[:]
    QUEUED.clear()
    if not queued:
        return []

    def guarded(item):
        s, lock = item
        try:
            return s.run_dir, train_one(s)
        except Exception as e:  # noqa: BLE001  (kept and reported per run, as a sweep's failed job)
            return s.run_dir, e
        finally:
            lock.release()

    states = [s for s, _ in queued]
    if all(s.cfg.train.get("stack", False) for s in states):
        from disent.stack import why_not_stacked

        if (why := why_not_stacked(states)) is None:
            return train_stacked_queued(queued)
        print(f"train.stack: training side by side instead ({why})")
    print(f"training {len(queued)} run(s) together: " + ", ".join(str(s.run_dir) for s, _ in queued))
    with ThreadPoolExecutor(len(queued), "run") as pool:
        return list(pool.map(guarded, queued))


def train_stacked_queued(queued: list) -> list[tuple[Path, dict | BaseException]]:
    """The queued runs as one stacked model (:mod:`disent.stack`), then each one's evaluation; an error in the
    stacked training stops every run."""
    from disent.stack import train_stacked

    states = [s for s, _ in queued]
    print(f"training {len(states)} run(s) stacked: " + ", ".join(str(s.run_dir) for s in states))
    try:
        ends = train_stacked(states)
        results = []
        for s, (stopped, batch) in zip(states, ends):
            try:
                results.append((s.run_dir, finish(s, stopped, batch)))
            except Exception as e:  # noqa: BLE001  (reported per run)
                results.append((s.run_dir, e))
        return results
    except Exception as e:  # noqa: BLE001  (the stack stopped: every run ends with its error)
        return [(s.run_dir, e) for s in states]
    finally:
        for _, lock in queued:
            lock.release()
