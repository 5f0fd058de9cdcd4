"""The time-budgeted training loop shared by the detector's two networks (PyTorch, CPU).

:func:`fit` runs AdamW with a linear warm-up and a cosine learning-rate schedule over a
wall-time budget (or a step budget, whichever ends first), logs every 50 steps to
``out/log.jsonl``, validates every ``eval_every`` steps and at the end, keeps the checkpoint with
the best validation F1 as ``best.pt`` (``last.pt`` is the latest) and leaves the chosen one loaded
in the model. Used by :mod:`uav_struct_env.training.train_detector` and
:mod:`uav_struct_env.training.train_refiner`.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Callable, Iterable
from pathlib import Path

import torch
from torch import nn

from uav_struct_env.errors import UsageError
from uav_struct_env.outputs import atomic_path, open_append
from uav_struct_env.validate import check_input_file, check_option, check_output_dir

__all__ = ["add_training_arguments", "check_training_arguments", "fit", "make_loader"]


def add_training_arguments(ap: argparse.ArgumentParser, *, minutes: float, batch: int,
                           lr: float) -> None:
    """Add the command-line options both trainers share, with per-network defaults.

    ``--minutes --max-steps --batch --lr --width --seed --threads --workers --eval-every --init``.
    """
    ap.add_argument("--minutes", type=float, default=minutes, help="wall-time budget")
    ap.add_argument("--max-steps", type=int, default=None, help="step budget (none: time only)")
    ap.add_argument("--batch", type=int, default=batch, help="batch size")
    ap.add_argument("--lr", type=float, default=lr, help="peak learning rate")
    ap.add_argument("--width", type=int, default=16, help="network width (channels)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=2, help="torch threads")
    ap.add_argument("--workers", type=int, default=1, help="data-loading processes")
    ap.add_argument("--eval-every", type=int, default=500, help="validation period, steps")
    ap.add_argument("--init", default=None, metavar="ONNX",
                    help="fine-tune: start from these exported weights (same architecture and "
                         "--width; batch norms frozen) instead of from scratch")
    ap.add_argument("--overwrite", action="store_true",
                    help="train into an --out folder that already holds files (else refused)")


def check_training_arguments(a: argparse.Namespace) -> None:
    """Check the options of :func:`add_training_arguments` and ``--data`` / ``--val`` / ``--out``.

    Every dataset is read (:func:`~uav_struct_env.datasets.landmarks.load_labels`) and the output
    folder checked (:func:`uav_struct_env.validate.check_output_dir`) before training starts.

    Raises:
        UsageError (or OutputExistsError): naming the option and what was expected.
    """
    from uav_struct_env.datasets.landmarks import load_labels

    check_option("--minutes", a.minutes, 0, lo_open=True)
    if a.max_steps is not None:
        check_option("--max-steps", a.max_steps, 1, integer=True)
    check_option("--batch", a.batch, 1, integer=True)
    check_option("--lr", a.lr, 0, lo_open=True)
    check_option("--width", a.width, 1, integer=True)
    check_option("--seed", a.seed, 0, integer=True)
    check_option("--threads", a.threads, 1, integer=True)
    check_option("--workers", a.workers, 0, integer=True)
    check_option("--eval-every", a.eval_every, 1, integer=True)
    if a.init is not None:
        check_input_file(a.init, option="--init", what="ONNX file")
    check_output_dir(a.out, overwrite=a.overwrite)
    data = a.data if isinstance(a.data, list) else [a.data]
    for option, paths in (("--data", data), ("--val", [a.val] if a.val else [])):
        for path in paths:
            try:
                load_labels(path)
            except (OSError, ValueError) as err:
                raise UsageError(f"{option} {path!r} is not a landmark dataset: {err}") from None


def make_loader(dataset: torch.utils.data.Dataset, batch: int, workers: int,
                seed: int) -> torch.utils.data.DataLoader:
    """A shuffled, seeded loader of full batches."""
    return torch.utils.data.DataLoader(
        dataset, batch_size=batch, shuffle=True, num_workers=workers, drop_last=True,
        generator=torch.Generator().manual_seed(seed), persistent_workers=workers > 0)


def fit(model: nn.Module, loader: Iterable, step_loss: Callable, out_dir: Path, *,
        minutes: float, max_steps: int | None, lr: float, warmup_steps: int,
        validate: Callable[[], dict] | None, eval_every: int, log=print) -> dict:
    """Train ``model`` in place; returns ``{"steps", "wall_s", "checkpoint"[, "best_val"]}``.

    Args:
        model: the network (its parameters are optimized; ``train()`` mode is restored after
            every validation).
        loader: batches, iterated again whenever it is exhausted.
        step_loss: ``batch -> (loss, {name: tensor})``; the named terms are logged.
        out_dir: where ``log.jsonl``, ``last.pt`` and ``best.pt`` go.
        minutes: wall-time budget; the cosine schedule runs over it.
        max_steps: optional step budget (the schedule then runs over whichever ends first).
        lr: peak learning rate (AdamW, weight decay 1e-4).
        warmup_steps: steps of the linear warm-up.
        validate: ``() -> metrics`` with an ``"f1"`` entry, or None for no validation.
        eval_every: validation period, steps.
        log: called with every logged record.

    Raises:
        ValueError: the loader yields no batch (fewer samples than one batch).
    """
    out_dir = Path(out_dir)
    opt = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=1e-4)
    budget = minutes * 60.0
    t0 = time.perf_counter()
    step, best, summary, ema = 0, -1.0, {}, None
    logf = open_append(out_dir / "log.jsonl")  # a link left there is replaced, not followed

    def write(rec: dict) -> None:
        logf.write(json.dumps(rec) + "\n")
        logf.flush()
        log(rec)

    def run_validation(final: bool) -> None:
        nonlocal best
        metrics = validate()
        metrics.update(step=step, time_s=round(time.perf_counter() - t0, 1))
        write({"val": metrics})
        if metrics["f1"] > best or (final and metrics["f1"] >= best):
            best = metrics["f1"]
            _save(model, out_dir / "best.pt")
            summary["best_val"] = metrics
        model.train()

    done = False
    while not done:
        before = step
        for batch in loader:
            elapsed = time.perf_counter() - t0
            frac = elapsed / budget
            if max_steps is not None:
                frac = max(frac, step / max_steps)
            if frac >= 1.0:
                done = True
                break
            warm = min(1.0, (step + 1) / warmup_steps)
            for g in opt.param_groups:
                g["lr"] = lr * warm * 0.5 * (1 + math.cos(math.pi * frac))
            loss, terms = step_loss(batch)
            opt.zero_grad()
            loss.backward()
            opt.step()
            step += 1
            ema = loss.item() if ema is None else 0.98 * ema + 0.02 * loss.item()
            if step % 50 == 0:
                write({"step": step, "time_s": round(elapsed, 1), "loss": round(ema, 4),
                       **{k: round(v.item(), 4) for k, v in terms.items()},
                       "lr": opt.param_groups[0]["lr"]})
            if validate is not None and step % eval_every == 0:
                run_validation(final=False)
            if step % 200 == 0:
                _save(model, out_dir / "last.pt")
        if not done and step == before:
            raise ValueError("the loader yielded no batch: fewer training samples than one batch "
                             "(drop_last); give a smaller batch or more data")
    _save(model, out_dir / "last.pt")
    if validate is not None:
        run_validation(final=True)
    logf.close()
    chosen = out_dir / ("best.pt" if (out_dir / "best.pt").exists() else "last.pt")
    model.load_state_dict(torch.load(chosen))
    summary.update(steps=step, wall_s=round(time.perf_counter() - t0, 1), checkpoint=chosen.name)
    return summary


def _save(model: nn.Module, path: Path) -> None:
    """``torch.save`` of the weights, atomically: a checkpoint on disk is always complete."""
    with atomic_path(path) as tmp:
        torch.save(model.state_dict(), tmp)
