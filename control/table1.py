"""The Table I analog of seed 000: every target x task scenario run closed loop (push-only MPC)
and open loop (the eq. 22 pushes of the initial J_s) on the same plant, scored by ITAE,
steady-state error and retraction, written as JSON, Markdown and HTML (each file whole).

``run_table1(case, targets, loop, settings, out)`` runs the scenarios (``loop`` from
``control.plants.build_loop``), writing the tables after every scenario so an interrupted run
keeps what it finished, and with ``resume`` a run in a folder that holds such a table runs only
the scenarios it lacks (``finished_rows``: the table's meta must be the run's, else it is
refused naming each difference, and a file that is no such table is refused too, the file left
as it is either way); a loop that runs long reports its step every ``STEP_LINE_S`` seconds (a
plant solve on a fine mesh takes minutes, a loop up to half an hour). With ``jobs`` > 1 the
scenarios run in that many worker processes, each building its own loop with ``loop_factory``
(the plant's solver state cannot cross processes); the rows are the serial run's, in the same
order, within round-off: every loop runs with ``LOOP_BLAS_THREADS`` BLAS threads, and a
reference solve does not depend on what its process solved before.
"""
from __future__ import annotations

import dataclasses
import json
import textwrap
import time
import warnings
from html import escape as html_escape
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from tissue_reference.control.controllability import UnreachableGoalError
from tissue_reference.control.loop import SSE_GOAL_MM, LoopStopped, plot_response
from tissue_reference.errors import CaseError, CaseReadError, ConvergenceError, TissueWarning
from tissue_reference.meshes.html_page import Raw, image, kv_table, page, table, write_page
from tissue_reference.meshes.io import atomic_path, save_figure
from tissue_reference.model.results import json_ready, write_json

__all__ = ["LOOP_BLAS_THREADS", "SSE_GOAL_MM", "STEP_LINE_S", "finished_rows", "plot_scenarios",
           "run_table1", "table1_meta", "table1_pairs", "table1_row", "table1_summary",
           "write_scenarios_page", "write_table1"]


LOOP_BLAS_THREADS = 1
"""BLAS and OpenMP threads of every loop, in this process or a worker: the thread count
changes the factorizations' round-off, and at a marginal load round-off can decide whether a
plant solve converges (the glued phantom at size 10, A1 = 80 mm: converged with one thread,
given up at load fraction 0.997 with two). One count everywhere makes ``jobs`` change only
the time a table takes, never a row beyond round-off."""


STEP_LINE_S = 60.0
"""A Table I loop passes on its closed- and open-loop step lines (``control.plant_step.
step_line``, prefixed by target and task) at most once per this many seconds, the first after
that long: loops of a second say nothing, loops of minutes say where they are."""


class _StepLines:
    """A loop's step lines, at most one per ``seconds`` (the first after ``seconds``), prefixed
    by ``prefix`` and handed to ``emit``."""

    def __init__(self, emit, prefix: str, seconds: float):
        self.emit, self.prefix, self.seconds = emit, prefix, float(seconds)
        self.last = time.monotonic()

    def __call__(self, line: str) -> None:
        now = time.monotonic()
        if now - self.last >= self.seconds:
            self.last = now
            self.emit(f"{self.prefix}: {line}")


def _fmt(v, spec):
    return "" if v is None else format(v, spec)


def table1_row(t, task, res) -> dict:
    """One scenario of Table I from a LoopResult (open loop included); ``at_push_limit``: the
    actuators that ended at the push limit (a loop that ends there short of its goal could not
    reach it within the limit: its row's note says so)."""
    d = res.to_json_dict()
    ol = d["open_loop"]
    return {"target": t, "task": task, "status": "ok", "open_loop_status": ol["status"],
            "outside_range": d["outside_range"],
            "open_loop_outside_range": ol.get("outside_range", []),
            "closed_loop_itae": d["itae"], "open_loop_itae": ol["itae"],
            "closed_loop_sse_mm": d["steady_state_error_mm"],
            "open_loop_sse_mm": ol["steady_state_error_mm"],
            "open_loop_converged": ol.get("converged", True),
            "open_loop_failed_at_step": ol.get("failed_at_step"),
            "open_loop_failed_pushes_mm": ol.get("failed_pushes_mm"),
            "open_loop_last_error_mm": ol.get("last_error_mm"),
            "u_open_mm": ol.get("u_open_mm"),
            "u_open_unclamped_mm": ol.get("u_open_unclamped_mm"),
            "final_pushes_mm": d["actuator_positions_mm"][-1],
            "preload_mm": d["preload_mm"], "at_push_limit": d["at_push_limit"],
            "max_retraction_mm": d["max_retraction_mm"],
            "mpc_step_median_ms": d["mpc_step_median_ms"], "wall_time_s": res.wall_time_s,
            "closed_loop_s": res.extra.get("closed_loop_s"),
            "model_time_s": res.extra.get("model_time_s"),
            "open_loop_s": res.extra.get("open_loop_s"),
            "cold_retries": {"plant": len(res.extra.get("plant_retries", [])),
                             "model": len(res.extra.get("model_retries", [])),
                             "open_loop_plant": len((res.open_loop or {}).get("retries", []))}}


def table1_summary(rows, n_expected) -> dict:
    """The closed-loop criteria over the rows: sse <= 0.05 mm, closed ITAE < open ITAE wherever
    the open loop is feasible (it completed: an open loop clamped to the push limit or cut short
    by a plant failure is reported, not compared), zero retraction -- each counted over the
    scenarios that ran; and none whose closed or open loop pushed past the range where the
    plant's or the model's answers converge (``outside_range``)."""
    ok = [r for r in rows if r["status"] == "ok"]
    sse = [r for r in ok if r["closed_loop_sse_mm"] <= SSE_GOAL_MM]
    # wherever the open loop is feasible: it completed (not clamped to the push limit, not cut
    # short by a plant that could not be solved at its pushes)
    feasible = [r for r in ok if r.get("open_loop_status", "completed") == "completed"
                and r["open_loop_converged"]]
    itae = [r for r in feasible if r["closed_loop_itae"] < r["open_loop_itae"]]
    retr = [r for r in ok if r["max_retraction_mm"] == 0.0]
    # loops that pushed past the range where the plant's or the model's answers converge
    outside = [r for r in ok if r.get("outside_range") or r.get("open_loop_outside_range")]
    return {"scenarios": n_expected, "ran": len(ok),
            "unreachable": sum(r["status"] == "unreachable" for r in rows),
            "failed": sum(r["status"] == "failed" for r in rows),
            "sse_le_0.05mm": len(sse), "closed_itae_lt_open": len(itae),
            "open_loop_feasible": len(feasible),
            "zero_retraction": len(retr),
            "open_loop_plant_failures": sum(not r["open_loop_converged"] for r in ok),
            "outside_range": len(outside),
            "worst_closed_loop_sse_mm": max((r["closed_loop_sse_mm"] for r in ok), default=None),
            "all_met": (len(ok) == n_expected and len(sse) == len(retr) == n_expected
                        and len(itae) == len(feasible) and not outside)}


def write_table1(out, meta, rows, n_expected):
    """table1.json, table1.md and table1.html in ``out`` (each written whole)."""
    out = Path(out)
    summ = table1_summary(rows, n_expected)
    write_json({"meta": meta, "summary": summ, "rows": rows}, out / "table1.json")
    hdr = ["Target", "Task", "Open-loop ITAE", "Closed-loop ITAE", "Open-loop SSE (mm)",
           "Closed-loop SSE (mm)", "Max retraction (mm)", "Final pushes (mm)", "Note"]
    body = []
    for r in rows:
        if r["status"] != "ok":
            body.append([r["target"], str(r["task"]), "", "", "", "", "", "",
                         f"{r['status']}: {r['error']}"])
            continue
        note = ""
        oitae = _fmt(r["open_loop_itae"], ".2f")
        if not r["open_loop_converged"]:
            oitae = ">= " + oitae
            note = (f"open loop: plant failed at step {r['open_loop_failed_at_step']} (pushes "
                    f"{[round(v, 2) for v in r['open_loop_failed_pushes_mm']]} mm; error "
                    f"{r['open_loop_last_error_mm']:.3f} mm at the last step solved)")
        if r.get("open_loop_status") == "infeasible" and r.get("u_open_unclamped_mm"):
            note = "; ".join(filter(None, [note, (
                f"open loop infeasible: its eq. 22 pushes "
                f"{[round(v, 2) for v in r['u_open_unclamped_mm']]} mm beyond the preload were "
                f"clamped to the push limit")]))
        if r.get("at_push_limit") and r["closed_loop_sse_mm"] > SSE_GOAL_MM:
            note = "; ".join(filter(None, [note, (
                f"closed loop held at the push limit by {', '.join(r['at_push_limit'])}: the "
                f"goal lies beyond the pushes the limit allows")]))
        for side, key in (("closed loop", "outside_range"),
                          ("open loop", "open_loop_outside_range")):
            if r.get(key):
                note = "; ".join(filter(None, [note, f"{side} outside the range where answers "
                                                     f"converge: " + "; ".join(r[key])]))
        body.append([r["target"], str(r["task"]), oitae, f"{r['closed_loop_itae']:.2f}",
                     _fmt(r["open_loop_sse_mm"], ".4f") or "not reached",
                     f"{r['closed_loop_sse_mm']:.2e}", f"{r['max_retraction_mm']:.3g}",
                     " ".join(f"{v:.2f}" for v in r["final_pushes_mm"]), note])
    verdict = (f"{summ['ran']}/{summ['scenarios']} scenarios ran; closed-loop SSE <= "
               f"{SSE_GOAL_MM} mm in {summ['sse_le_0.05mm']}, closed ITAE < open ITAE in "
               f"{summ['closed_itae_lt_open']} of {summ['open_loop_feasible']} with a feasible "
               f"open loop, zero retraction in {summ['zero_retraction']}; "
               f"outside the range where answers converge: {summ['outside_range']}; "
               f"worst closed-loop SSE {_fmt(summ['worst_closed_loop_sse_mm'], '.2e')} mm")
    title = f"Table I analog: {json.dumps(meta)}"
    md = [title, "", verdict, "", "| " + " | ".join(hdr) + " |", "|" + "---|" * len(hdr)]
    md += ["| " + " | ".join(b) + " |" for b in body]
    with atomic_path(out / "table1.md") as tmp:
        tmp.write_text("\n".join(md) + "\n")
    png = [f"response_{r['target']}_task{r['task']}.png" for r in rows if r["status"] == "ok"]
    png = [p for p in png if (out / p).is_file()]
    scen = meta.get("scenario")
    parts = [Raw(f"<h1>Table I analog{': ' + html_escape(str(scen)) if scen else ''}</h1>"),
             meta.get("scenario_description") or "",
             table([h.replace("ITAE", "ITAE (mm·s²)") for h in hdr], body, caption=verdict)]
    if png:
        parts.append(Raw("<h2>Trajectories (closed loop, open loop, goal; actuator pushes)</h2>"))
        parts += [image(p, f"time response {p}", p, 640) for p in png]
    parts += [Raw("<h2>Settings</h2>"), kv_table(meta)]
    write_page(out / "table1.html", page("Table I analog", parts))
    return summ


_START_OVER = ("choose another --out folder, delete the file, or start over in this folder "
               "(--restart; resume=False in Python), which replaces its rows")
"""What a refused resume can do instead (``finished_rows``)."""


def _differences(old, new, prefix: str = "") -> list[str]:
    """The keys (dotted paths) whose values differ between two JSON-ready dicts."""
    out = []
    for key in sorted(set(old) | set(new), key=str):
        a, b = old.get(key), new.get(key)
        name = f"{prefix}{key}"
        if isinstance(a, dict) and isinstance(b, dict):
            out += _differences(a, b, name + ".")
        elif json.dumps(a, sort_keys=True) != json.dumps(b, sort_keys=True):   # NaN == NaN
            out.append(f"{name} ({json.dumps(a)} there, {json.dumps(b)} now)")
    return out


def table1_pairs(targets) -> list[tuple[str, int]]:
    """The (target, task) pair of every row of a table of ``targets``, in the table's order."""
    return [(t, task) for t in targets for task in (1, 2, 3)]


def table1_meta(loop, settings, meta=None) -> dict:
    """The ``meta`` a table of ``loop`` and ``settings`` records, and a resume compares:
    ``meta`` as given (the command line's: the loop's meta with its settings), else the loop's
    own ``meta`` (``control.plants.LoopSetup``: case, plant, model, mismatch); with the loop's
    ``settings`` (``control.loop.LoopSettings``, as a dict) where it has none."""
    meta = dict(meta if meta is not None else (getattr(loop, "meta", None) or {}))
    if "settings" not in meta and dataclasses.is_dataclass(settings):
        meta["settings"] = dataclasses.asdict(settings)
    return json_ready(meta)


def _read_table(path: Path) -> tuple[dict, list[dict], list[tuple[str, int]]]:
    """(meta, rows, their (target, task) pairs) of a table1.json; CaseReadError naming the file
    and what is wrong when it is not such a table."""
    try:
        data = json.loads(path.read_text())
        if not isinstance(data, dict):
            raise TypeError(f"a JSON {type(data).__name__}, not an object")
        meta, rows = data["meta"], data["rows"]
        if not isinstance(meta, dict):
            raise TypeError("its meta is not an object")
        if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
            raise TypeError("its rows are not a list of objects")
        keys = [(r["target"], r["task"]) for r in rows]
        bad = [k for k in keys if not isinstance(k[0], str) or k[1] not in (1, 2, 3)
               or isinstance(k[1], bool)]
        if bad:
            raise ValueError(f"a row of target {bad[0][0]!r} task {bad[0][1]!r}")
    except (OSError, ValueError, KeyError, TypeError) as exc:
        why = f"no key {exc}" if isinstance(exc, KeyError) else str(exc)
        raise CaseReadError(f"{path}: not a Table I table to resume from ({why}); it is left "
                            f"as it is: {_START_OVER}") from None
    return meta, rows, keys


def finished_rows(out, meta, pairs) -> dict:
    """The rows an earlier run left in ``out``/table1.json, by their index in ``pairs`` (the
    (target, task) pairs of this run); {} when there is no table. Every finished row stays, a
    failed or unreachable loop too (a loop's outcome depends on its settings alone). Refused,
    the file left as it is: a table of other settings (its ``meta`` against ``meta``, every
    difference named with both values: CaseError), a row of a pair this run does not ask for
    (CaseError), a file that is not such a table (CaseReadError)."""
    path = Path(out) / "table1.json"
    if not path.is_file():
        if path.exists() or path.is_symlink():
            raise CaseReadError(f"{path}: not a file, so not a Table I table to resume from; "
                                f"{_START_OVER}")
        return {}
    old_meta, rows, keys = _read_table(path)
    differ = _differences(old_meta, json_ready(meta))
    if differ:
        raise CaseError(f"{path}: its rows were run with other settings: "
                        f"{'; '.join(differ)}; resuming needs the same settings: {_START_OVER}")
    index = {(t, int(task)): i for i, (t, task) in enumerate(pairs)}
    foreign = [f"{t} task {task}" for t, task in keys if (t, task) not in index]
    if foreign:
        raise CaseError(f"{path}: it has rows this run does not ask for ({', '.join(foreign)}): "
                        f"resume with the same targets, {_START_OVER}")
    return {index[k]: row for k, row in zip(keys, rows)}


def run_one(loop, t, task, settings, out, plots: bool = True,
            step_lines=None) -> tuple[dict, str]:
    """One scenario of Table I on ``loop``: (its row, its progress line); a time-response PNG
    in ``out`` when it completes and ``plots``. ``step_lines(line)``: where its step lines go,
    one per ``STEP_LINE_S`` at most (None: nowhere)."""
    steps = None if step_lines is None else _StepLines(step_lines, f"{t} task {task}",
                                                       STEP_LINE_S)
    try:
        with threadpool_limits(limits=LOOP_BLAS_THREADS):
            res = loop.run(t, task, settings) if steps is None else \
                loop.run(t, task, settings, progress=steps)
    except UnreachableGoalError as exc:
        return ({"target": t, "task": task, "status": "unreachable", "error": str(exc),
                 "closest_reachable_mm": np.asarray(exc.closest).tolist()},
                f"{t} task {task}: unreachable: {exc}")
    except ConvergenceError as exc:   # LoopStopped: with the step, pushes and history
        return ({"target": t, "task": task, "status": "failed", "error": str(exc),
                 **(exc.to_json_dict() if isinstance(exc, LoopStopped) else {})},
                f"{t} task {task}: closed loop failed: {exc}")
    row = table1_row(t, task, res)
    line = (f"{t} task {task}: itae closed {row['closed_loop_itae']:.2f} open "
            f"{'' if row['open_loop_converged'] else '>= '}"
            f"{_fmt(row['open_loop_itae'], '.2f')} ({row['open_loop_status']})"
            f"  sse closed {row['closed_loop_sse_mm']:.2e} open "
            f"{_fmt(row['open_loop_sse_mm'], '.4f') or 'not reached'} mm  "
            f"retraction {row['max_retraction_mm']}  ({res.wall_time_s:.1f} s)")
    if plots:
        plot_response(res, Path(out) / f"response_{t}_task{task}.png")
    return row, line


_WORKER = {}   # in a worker process: its loop factory, its key and the loop it built


def _print_line(line: str) -> None:
    print(line, flush=True)


def _worker_init(factory, key, quiet, step_lines):
    _WORKER.update(factory=factory, key=key, loop=None,
                   step_lines=_print_line if step_lines else None)
    if quiet:   # the parent (the command line) prints its own lines instead
        warnings.simplefilter("ignore", TissueWarning)


def _worker_run(t, task, settings, out, plots):
    if _WORKER["loop"] is None:
        with threadpool_limits(limits=LOOP_BLAS_THREADS):   # one core per worker
            _WORKER["loop"] = _WORKER["factory"](_WORKER["key"])
    return run_one(_WORKER["loop"], t, task, settings, out, plots, _WORKER["step_lines"])


def _ignoring_warnings() -> bool:
    """Whether this process ignores TissueWarning (the command line does)."""
    return any(f[0] == "ignore" and isinstance(f[2], type) and issubclass(TissueWarning, f[2])
               for f in warnings.filters)


def run_table1(case, targets, loop, settings, out, *, meta=None, progress=print,
               plots: bool = True, jobs: int = 1, loop_factory=None, factory_key=None,
               step_lines: bool = True, resume: bool = False) -> dict:
    """Every target x task (1, 2, 3) on ``loop`` (``control.plants.LoopSetup``); returns the
    summary. ``meta``: what the table records of the run, and what a resume compares
    (``table1_meta``; default: the loop's meta and ``settings``). ``resume``: keep the rows an
    earlier run of the same meta left in ``out`` (``finished_rows``; a progress line names
    them) and run only the others; otherwise the table starts empty.
    ``progress(line)`` gets one line per scenario as it ends and, with
    ``step_lines``, a long loop's step lines (``STEP_LINE_S``; a worker process prints its own
    to stdout); ``plots``: a time-response PNG per scenario in ``out``. ``jobs`` > 1: that many
    worker processes, each running ``loop_factory(factory_key)`` once for its own loop (a
    picklable callable: a module-level function or a functools.partial of one); ``loop`` then
    serves nobody."""
    pairs = table1_pairs(targets)
    n = len(pairs)
    meta = table1_meta(loop, settings, meta)
    done = finished_rows(out, meta, pairs) if resume else {}
    todo = [(i, pair) for i, pair in enumerate(pairs) if i not in done]

    def write():   # the table of the rows done, in the pairs' order (each time one ends)
        return write_table1(out, meta, [done[k] for k in sorted(done)], n)

    summ = table1_summary([], n)
    if done:
        kept = ", ".join(f"{t} task {task}" for t, task in (pairs[i] for i in sorted(done)))
        progress(f"table1: resuming from {Path(out) / 'table1.json'}: {len(done)} of {n} "
                 f"loops finished there, {len(todo)} to run; taken from it: {kept}")
        summ = write()

    def finish(i, row, line):
        nonlocal summ
        done[i] = row
        progress(line)
        summ = write()

    if jobs <= 1 or len(todo) <= 1:
        for i, pair in todo:
            finish(i, *run_one(loop, *pair, settings, out, plots,
                               progress if step_lines else None))
        return summ
    if loop_factory is None:
        raise ValueError("run_table1: jobs > 1 needs a loop_factory")
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    Path(out).mkdir(parents=True, exist_ok=True)
    init = (loop_factory, factory_key, _ignoring_warnings(), bool(step_lines))
    with ProcessPoolExecutor(max_workers=min(jobs, len(todo)),
                             mp_context=multiprocessing.get_context("spawn"),
                             initializer=_worker_init, initargs=init) as pool:
        futures = {pool.submit(_worker_run, *pair, settings, out, plots): i for i, pair in todo}
        for fut in as_completed(futures):
            finish(futures[fut], *fut.result())
    return summ


def plot_scenarios(results: dict, path) -> Path:
    """Closed- vs open-loop ITAE of every scenario (target x task), one panel per mismatch
    scenario; ``results``: scenario -> rows of ``table1_row``. PNG written whole."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(results)
    fig, axes = plt.subplots(1, len(names), figsize=(5.2 * len(names), 3.8), squeeze=False)
    for ax, name in zip(axes[0], names):
        ok = [r for r in results[name] if r["status"] == "ok"]
        if not ok:
            why = next((r.get("error", "") for r in results[name]), "")
            ax.text(0.5, 0.5, "no scenario ran\n" + textwrap.fill(why[:300], 50),
                    ha="center", va="center", fontsize=7, transform=ax.transAxes, wrap=True)
            ax.set_title(f"mismatch: {name}")
            ax.set_xticks([])
            ax.set_yticks([])
            continue
        labels = [f"{r['target']}/{r['task']}" for r in ok]
        x = np.arange(len(ok))
        ax.bar(x - 0.2, [r["closed_loop_itae"] for r in ok], 0.4, label="closed loop")
        ax.bar(x + 0.2, [r["open_loop_itae"] or 0.0 for r in ok], 0.4, label="open loop",
               color=["C1" if r.get("open_loop_status") == "completed" else "0.7" for r in ok])
        ax.set_xticks(x, labels, rotation=90, fontsize=7)
        ax.set_yscale("log")
        ax.set_title(f"mismatch: {name}")
        ax.set_ylabel("ITAE (mm s^2)")
        ax.legend(fontsize=7)
    fig.tight_layout()
    path = Path(path)
    save_figure(fig, path)
    return path


def write_scenarios_page(out, summaries: dict, metas: dict, settings: dict | None,
                         plot: str | None = None) -> Path:
    """``out``/table1_scenarios.html: per mismatch scenario its summary and a link to its own
    table (``NAME/table1.html``), the ITAE plot ``plot`` (a PNG in ``out``) and the settings."""
    out = Path(out)
    rows = [(Raw(f"<a href='{html_escape(n)}/table1.html'>{html_escape(n)}</a>"),
             metas.get(n, {}).get("scenario_description", ""), f"{v['ran']}/{v['scenarios']}",
             v["sse_le_0.05mm"], f"{v['closed_itae_lt_open']}/{v['open_loop_feasible']}",
             v["zero_retraction"], _fmt(v["worst_closed_loop_sse_mm"], ".2e"),
             "yes" if v["all_met"] else "no") for n, v in summaries.items()]
    parts = [Raw("<h1>Table I analog per model-plant mismatch</h1>"),
             table(["scenario", "mismatch", "ran", f"SSE <= {SSE_GOAL_MM} mm (count)",
                    "closed ITAE < open ITAE (count of feasible)", "zero retraction (count)",
                    "worst closed-loop SSE (mm)", "all met"], rows)]
    if plot and (out / plot).is_file():
        parts.append(image(plot, "closed- and open-loop ITAE per scenario",
                           "closed- against open-loop ITAE (mm·s²) of every target and task; "
                           "grey: open loop not feasible", 900))
    parts += [Raw("<h2>Settings</h2>"), kv_table(settings or {})]
    return write_page(out / "table1_scenarios.html", page("Table I analog: scenarios", parts))
