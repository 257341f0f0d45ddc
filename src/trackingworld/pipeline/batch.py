"""``trackingworld run`` over many videos: one result folder each, a failure reported and passed over, finished
videos skipped on a re-run, and a summary that is rewritten after every video (``ROOT/batch.json``).

The per-video work is :func:`trackingworld.pipeline.run.run`, unchanged; this module only names the folders,
fills in each video's prior files and keeps the account. A video's run is finished when its folder holds
``result.npz`` and ``timings.json``: the run writes every file atomically (``io.atomic``) and ``timings.json``
last, so a batch killed mid-video leaves nothing that a re-run would take for finished.
"""

from __future__ import annotations

import sys
import time
import traceback
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import replace
from multiprocessing import get_context
from pathlib import Path

from trackingworld.config import RunConfig
from trackingworld.errors import InputError
from trackingworld.io.atomic import write_json
from trackingworld.io.result import RESULT_FILE
from trackingworld.optim.parallel import cpu_count, set_thread_cap
from trackingworld.pipeline.run import TIMINGS_FILE, check_run, run
from trackingworld.priors.sources import depth_source, mask_source

SUMMARY_FILE = "batch.json"
NAME_FIELD = "{name}"  # in a prior's path: replaced by each video's name


def video_name(path: str) -> str:
    """The name of a video's result folder: a file's stem, or an image folder's own name."""
    p = Path(path.rstrip("/\\"))
    return p.name if p.is_dir() else p.stem


def video_names(inputs: list[str]) -> list[str]:
    """Each input's folder name; InputError when two inputs would share one (one line naming them)."""
    names = [video_name(i) for i in inputs]
    seen: dict[str, str] = {}
    for i, n in zip(inputs, names, strict=True):
        if n in seen:
            raise InputError(f"{seen[n]} and {i}: both would write to the result folder {n!r}; rename one of them")
        seen[n] = i
    return names


def check_per_video(cfg: RunConfig) -> None:
    """Settings that name one file cannot serve several videos: a depth or mask file, or a tracks file, must hold
    ``{name}``. An intrinsics file may be shared (one camera)."""
    ic = cfg.inputs
    for flag, value, is_file in (("--depth", ic.depth, depth_source(ic.depth) == "file"),
                                 ("--masks", ic.masks, mask_source(ic.masks) == "file"),
                                 ("--tracks", cfg.track2d.tracks_file, cfg.track2d.tracker == "file")):
        if is_file and NAME_FIELD not in (value or ""):
            raise InputError(f"{flag} {value}: one file for several videos; write the path with {NAME_FIELD} "
                             f"(e.g. depth/{NAME_FIELD}.npy), or give a model, the weight-free default or none")


def config_for(cfg: RunConfig, input_path: str, name: str) -> RunConfig:
    """``cfg`` for one video: its input, and ``{name}`` in the prior and tracks paths replaced by its name."""

    def fill(value: str | None) -> str | None:
        return value.replace(NAME_FIELD, name) if value else value

    ic = cfg.inputs
    inputs = replace(ic, input=input_path, depth=fill(ic.depth), masks=fill(ic.masks), intrinsics=fill(ic.intrinsics))
    return replace(cfg, inputs=inputs, track2d=replace(cfg.track2d, tracks_file=fill(cfg.track2d.tracks_file)))


def finished(out: Path) -> bool:
    """A result folder that holds a finished run (module docstring)."""
    return (out / RESULT_FILE).exists() and (out / TIMINGS_FILE).exists()


def run_video(cfg: RunConfig, path: str, name: str, out: Path, verbose: bool = True) -> dict:
    """One video of a batch: ``cfg`` on ``path`` into ``out``. Returns its entry (:func:`run_batch`); a failure is
    recorded in it, not raised (KeyboardInterrupt and MemoryError are)."""
    entry = {"input": path, "out": str(out), "status": "done", "seconds": 0.0}
    t0 = time.perf_counter()
    try:
        run(config_for(cfg, path, name), out, verbose=verbose)
    except InputError as e:
        entry.update(status="failed", error=str(e))
    except (KeyboardInterrupt, MemoryError):
        raise
    except Exception as e:  # one video's failure must not end a batch of a thousand
        entry.update(status="failed", error=f"{type(e).__name__}: {e}", traceback=traceback.format_exc())
    entry["seconds"] = round(time.perf_counter() - t0, 2)
    return entry


def run_batch(cfg: RunConfig, inputs: list[str], out_root: str | Path, skip_done: bool = False,
              verbose: bool = True, jobs: int = 1, threads: int | None = None) -> list[dict]:
    """Run ``cfg`` on every input into ``out_root/<name>/``. A video whose run fails (bad input or any error) is
    reported on one line and recorded, and the batch goes on; with ``skip_done`` a video whose folder holds a
    finished run (:func:`finished`) is not run again. ``out_root/batch.json`` (atomic) is rewritten after every
    video. Returns one entry per input, in their order: ``input``, ``out``, ``status`` (done / skipped / failed),
    ``seconds``, and for a failure ``error`` (one line) and ``traceback`` (for an error that is not an InputError).

    ``jobs`` > 1 runs that many videos at once, each in a process of its own with ``threads`` threads (None: the
    CPUs shared out, at least 1; ``optim.parallel.set_thread_cap``), their progress lines left out: most of a run is
    single-threaded work, so on a machine of many cores several videos at once finish a batch sooner than one at a
    time with every thread."""
    check_run(cfg)  # a bad setting fails once, before any video, not once per video
    check_per_video(cfg)
    if jobs < 1 or (threads is not None and threads < 1):
        raise InputError(f"--jobs {jobs} / --threads {threads}: both must be 1 or more")
    names = video_names(inputs)
    root = Path(out_root)
    entries: list[dict | None] = [None] * len(inputs)
    outs = [root / n for n in names]
    head = [f"[batch] {k}/{len(inputs)} {p} -> {o}" for k, (p, o) in enumerate(zip(inputs, outs, strict=True), 1)]

    def record(k: int, entry: dict) -> None:
        entries[k] = entry
        if entry["status"] != "skipped":
            tail = f"failed: {entry['error']}" if entry["status"] == "failed" else f"done in {entry['seconds']:.1f} s"
            print(f"{head[k]}: {tail}", file=sys.stderr, flush=True)
        write_json(root / SUMMARY_FILE, summary([e for e in entries if e is not None], len(inputs)))

    todo = []
    for k, out in enumerate(outs):
        if skip_done and finished(out):
            print(f"{head[k]}: skipped, finished before", file=sys.stderr, flush=True)
            record(k, {"input": inputs[k], "out": str(out), "status": "skipped", "seconds": 0.0})
        else:
            todo.append(k)
    if jobs == 1 or len(todo) < 2:
        for k in todo:
            print(head[k], file=sys.stderr, flush=True)
            record(k, run_video(cfg, inputs[k], names[k], outs[k], verbose))
        return entries
    workers = min(jobs, len(todo))  # no more processes than videos, and the CPUs shared among those
    per_job = threads or max(1, cpu_count() // workers)
    with ProcessPoolExecutor(workers, mp_context=get_context("spawn"), initializer=set_thread_cap,
                             initargs=(per_job,)) as pool:
        futures = {pool.submit(run_video, cfg, inputs[k], names[k], outs[k], False): k for k in todo}
        for k in todo:
            print(f"{head[k]} (queued; {workers} at once, {per_job} threads each)", file=sys.stderr, flush=True)
        try:
            for fut in as_completed(futures):
                k = futures[fut]
                try:
                    entry = fut.result()
                except BrokenProcessPool:  # killed from outside, or by the kernel for memory: this video and the rest
                    entry = {"input": inputs[k], "out": str(outs[k]), "status": "failed", "seconds": 0.0,
                             "error": "its worker process died (killed, or out of memory); run it again alone"}
                record(k, entry)
        except KeyboardInterrupt:
            pool.shutdown(wait=False, cancel_futures=True)
            raise
    return entries


def summary(entries: list[dict], total: int) -> dict:
    """The batch's account: counts by status and every video's entry so far."""
    counts = {s: sum(e["status"] == s for e in entries) for s in ("done", "skipped", "failed")}
    return {"inputs": total, "finished": len(entries), **counts, "videos": entries}
