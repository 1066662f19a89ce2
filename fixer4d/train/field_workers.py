"""Several fields of one training at once, each in a worker process (``training.field_workers``).

One field's training is one Python thread that drives small torch ops and numba kernels between
them, so a second CPU thread speeds it up by far less than twice: `make run`'s two stage-1 fields
take 203 s one after the other on a 2-core host and 127 s side by side, one thread each
(docs/decisions/field-workers.md). The digits do not depend on it: the kernels' sums are fixed in
order whatever the thread count and torch computes on one thread (fixer4d/threads.py), so the run
with its fields in workers is the run without, byte for byte (tests/pipeline/test_field_workers_pipeline.py;
past 32,768 Gaussians a field: tests/train/test_thread_count_digits.py).

Workers are spawned, not forked: numba's OpenMP threading layer and torch share GNU libgomp,
which a forked child of a process that used it cannot use (numba terminates such a child). A
spawned worker therefore builds its field's trainer again from a ``FieldRecipe``: a top-level
function named by its module path and arguments that pickle (a run folder's path and config, a
fold's held-back camera), which load the scene and the finished init themselves.

    worker_count(training, pending) -> how many workers (1: the fields train one after the other
                                        in this process)
    plan_workers(training, n, scene_from_config, function, *args) -> (recipe or None, workers)
    train_in_workers(recipe, jobs, workers, label, save, progress)
        -> each (field, directory) of ``jobs`` trained to its end by a worker that writes the
           field's model and record into its directory (``save``); one progress bar over all of them; a
           failed worker stops the others and raises with its error; a killed run leaves every
           field's checkpoints to resume from
"""
from __future__ import annotations

import importlib
import multiprocessing as mp
import traceback
from dataclasses import dataclass
from multiprocessing.connection import wait
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Sequence

from fixer4d.errors import Fixer4DError, InputError

if TYPE_CHECKING:
    from fixer4d.train.config import TrainingConfig
    from fixer4d.train.trainer import Trainer

# How often the parent redraws the progress bar and looks for a finished worker, seconds.
POLL_SECONDS = 0.5


@dataclass(frozen=True)
class FieldRecipe:
    """How a worker process builds field k's untrained trainer: ``function`` ("package.module:name",
    top-level) called as ``function(*args, field=k, directory=out)``; ``args`` must pickle."""

    function: str
    args: tuple[Any, ...] = ()

    def build(self, field: int, directory: Path) -> "Trainer":
        module, _, name = self.function.partition(":")
        return getattr(importlib.import_module(module), name)(*self.args, field=field, directory=directory)


def cpu_budget() -> int:
    """The CPUs this process may keep busy: its compute threads (``fixer4d.jit.compute_threads``:
    what a study's executor grants a task), at most the usable CPUs (``fixer4d.cpus``)."""
    from fixer4d.cpus import usable_cpus
    from fixer4d.jit import compute_threads

    return max(1, min(usable_cpus(), compute_threads()))


def worker_count(training: "TrainingConfig", pending: int) -> int:
    """Workers for ``pending`` fields: ``training.field_workers`` (0: one per CPU of
    ``cpu_budget``), at most one per field; 1 on CUDA, where the GPU runs one field's kernels at a
    time anyway."""
    from fixer4d.train.device import device_kind

    if device_kind(training.device, training.backend) != "cpu":
        return 1
    wanted = training.field_workers if training.field_workers > 0 else cpu_budget()
    return max(1, min(int(wanted), int(pending)))


def plan_workers(training: "TrainingConfig", fields: int, scene_from_config: bool, function: str,
                 *args: Any) -> tuple[FieldRecipe | None, int]:
    """(recipe, workers) for a training of ``fields`` fields: a recipe calling ``function(*args,
    field=k, directory=out)`` where a worker can load the scene again (``scene_from_config``: the
    scene is ``load_scene_for(config)``) and more than one worker would run; else (None, 1), the
    fields one after the other in this process."""
    workers = worker_count(training, fields) if scene_from_config else 1
    return (FieldRecipe(function, args), workers) if workers > 1 else (None, 1)


def train_in_workers(recipe: FieldRecipe, jobs: Sequence[tuple[int, Path]], workers: int, label: str,
                     save: Callable[[Path, "Trainer"], Any], progress: bool = True) -> dict[int, float]:
    """Train every (field, directory) of ``jobs`` to its end in ``workers`` spawned processes (a new
    one starts as one ends), each on ``cpu_budget()`` // workers threads; every worker resumes its field
    from the checkpoints in its directory and writes the finished model and record there with
    ``save(directory, trainer)`` (top-level, so that it pickles: ``fields.save_field``). Returns
    {field: seconds trained by earlier attempts} (0 for a field that started afresh). Raises
    InputError or Fixer4DError with a worker's error (the others are stopped first)."""
    from tqdm import tqdm

    context = mp.get_context("spawn")
    workers = max(1, min(int(workers), len(jobs)))
    threads = max(1, cpu_budget() // workers)
    steps = context.Array("q", len(jobs), lock=False)  # each job's steps done (its worker writes them)
    totals = context.Array("q", len(jobs), lock=False)  # each job's total steps, once its worker knows
    waiting = list(range(len(jobs)))
    running: dict[int, tuple[Any, Any]] = {}  # job -> (process, the parent's end of its pipe)
    prior: dict[int, float] = {}
    fields = ", ".join(str(k + 1) for k, _ in jobs)
    bar = tqdm(total=0, disable=not progress, unit="it", dynamic_ncols=True,
               desc=f"{label}, fields {fields} ({workers} at once)")
    try:
        while waiting or running:
            while waiting and len(running) < workers:
                j = waiting.pop(0)
                field, directory = jobs[j]
                here, there = context.Pipe(duplex=False)
                process = context.Process(target=_work, args=(recipe, save, field, str(directory), threads, steps,
                                                              totals, j, there), name=f"fixer4d field {field}")
                process.start()
                there.close()
                running[j] = (process, here)
            ended = wait([p.sentinel for p, _ in running.values()], timeout=POLL_SECONDS)
            _draw(bar, steps, totals, len(jobs))
            for j in [j for j, (p, _) in running.items() if p.sentinel in ended]:
                process, here = running.pop(j)
                message = _message(here)
                process.join()
                here.close()
                prior[jobs[j][0]] = _outcome(message, process.exitcode, label, jobs[j][0])
        _draw(bar, steps, totals, len(jobs))
    finally:
        bar.close()
        for process, here in running.values():  # an error elsewhere, or the run was stopped
            process.terminate()
            process.join()
            here.close()
    return prior


def _message(pipe) -> tuple | None:
    """What a finished worker sent, None when it sent nothing (its end closed unwritten)."""
    try:
        return pipe.recv() if pipe.poll() else None
    except EOFError:
        return None


def _draw(bar, steps, totals, n_jobs: int) -> None:
    """Point the bar at the steps done over all jobs; a job whose worker has not said its total yet
    counts as the largest total known."""
    known = [t for t in totals[:] if t > 0]
    if known:
        bar.total = sum(known) + (n_jobs - len(known)) * max(known)
    bar.n = int(sum(steps[:]))
    bar.refresh()


def _outcome(message: tuple | None, exitcode: int | None, label: str, field: int) -> float:
    """A finished worker's seconds of earlier attempts, or its error raised here."""
    if message is not None and message[0] == "done":
        return float(message[1])
    if message is not None and message[0] == "error":
        _, kind, text = message
        error = InputError if kind == "input" else Fixer4DError
        raise error(f"{label}, field {field + 1}: {text}")
    raise Fixer4DError(f"{label}, field {field + 1}: its worker process ended with exit code {exitcode} before "
                       f"finishing (killed, or out of memory?); run the command again to resume from its checkpoints")


def _work(recipe: FieldRecipe, save, field: int, directory: str, threads: int, steps, totals, slot: int,
          pipe) -> None:
    """A worker process's body: build field ``field``'s trainer from ``recipe``, resume and train it
    (numba on ``threads`` threads, torch on ``DIGIT_TORCH_THREADS``), ``save`` its model and record,
    send ("done", seconds of earlier attempts) or ("error", "input" | "other", what went wrong)
    through ``pipe``."""
    import signal

    # Ctrl-C reaches the whole process group: the parent stops the workers (their checkpoints stay);
    # the parent's SIGTERM ends a worker through Python, so that its semaphores are released
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _exit_on_signal)
    try:
        from fixer4d.jit import set_compute_threads
        from fixer4d.threads import digit_threads

        set_compute_threads(threads)

        def on_step(step: int) -> None:
            steps[slot] = step

        with digit_threads():
            out = Path(directory)
            trainer = recipe.build(field, out)
            prior = trainer.train_seconds if trainer.resume() else 0.0
            totals[slot] = trainer.total_iterations
            steps[slot] = trainer.step_count
            trainer.train(progress=False, on_step=on_step)
            save(out, trainer)
        pipe.send(("done", prior))
    except SystemExit:
        raise
    except BaseException as exc:  # noqa: BLE001 - everything goes back to the parent, which raises it
        traceback.print_exc()
        pipe.send(("error", "input" if isinstance(exc, InputError) else "other", f"{type(exc).__name__}: {exc}"))
    finally:
        pipe.close()


def _exit_on_signal(signum: int, _frame) -> None:
    raise SystemExit(128 + signum)


__all__ = ["FieldRecipe", "cpu_budget", "worker_count", "plan_workers", "train_in_workers", "POLL_SECONDS"]
