"""The gap report: ``report.json`` (``gap-report.md``) and ``report.md`` with its plots."""

from __future__ import annotations

import re
import shutil
import tempfile
from pathlib import Path
from typing import Callable

import numpy as np

from uavturb.gap.decide import PRACTICAL_SHARE
from uavturb.gap.landed_heights import LandedHeights
from uavturb.gap.locate import AXES, features
from uavturb.gap.selection import Z_IMPROVE, last_step
from uavturb.gap.plotting import (
    COLUMNS_PER_PIXEL,
    column_envelope,
    gc_paused,
    grid_layout,
    hide_unused_cells,
    recording_grid,
    scatter_rows,
    shade_spans,
)
from uavturb.gap.surface_curve import SurfaceCurve
from uavturb.gap.surface_laws import LawFit
from uavturb.gap.uncertainty import BUDGET_TERMS, ONE_STRETCH_SHARE, TIME_BLOCKS, YAML_THRUST_DIFFERS
from uavturb.io.reader import recording_labels
from uavturb.physics.effects import EFFECTS
from uavturb.io.strict_json import dumps_strict
from uavturb.numerics.processes import ForkedPool, Started, forked_state, forking_possible

#: units of the candidate drivers of :func:`uavturb.gap.locate.features` (plot axes)
FEATURE_UNITS = {"d_down": "m", "d_up": "m", "v_x": "m/s", "v_y": "m/s", "v_z": "m/s", "v_Bx": "m/s", "v_By": "m/s",
                 "v_Bz": "m/s", "speed": "m/s", "rotor_speed_sum": "rad/s", "rotor_speed_rate": "rad/s^2",
                 "thrust_sum_omega2": "rad^2/s^2", "t": "s"}
#: report.md's words for each ``reason`` of a ``rejected`` entry (:func:`uavturb.gap.discovery.no_discovery`)
REJECTION_REASONS = {"outside_range": "outside its physical range", "too_small": "too small to matter",
                     "not_pinned": "not pinned by these flights"}
#: resolution of the report's PNG figures [dots per inch]
PLOT_DPI = 100
#: width [inch] of a recording's cell in a figure with a cell per recording (:func:`recording_grid`)
PANEL_WIDTH_IN = 6.0
#: share of the weight over which the nominal model's RMSE says something is wrong before any effect: real
#: flights leave a few percent (Neural-Swarm's Crazyflies 3.5-5.6 %, simulated PX4 troubles 2-8 %); a PX4
#: log whose ESC telemetry updates at 4 Hz through take-off, with a drifting height, left 36 %
NOMINAL_MISS_SHARE = 0.15
#: what "before" means in each plot: the two use different fits of the nominal model
BEFORE_ALL = "before (nominal model, robust fit on all data)"
BEFORE_HELDOUT = "before (nominal model fitted on the other folds)"


def format_params(params: dict | None, stderr: dict | None = None) -> str:
    """``mu = 1.9996 ± 0.0021, ...``: a value to the decimals of its standard error's two significant
    digits; without one, four significant digits."""
    if not params:
        return "-"
    out = []
    for k, v in params.items():
        se = (stderr or {}).get(k)
        if se is not None and np.isfinite(se) and se > 0:
            places = int(min(8, max(0, 1 - np.floor(np.log10(se)))))
            out.append(f"{k} = {v:.{places}f} ± {se:.{places}f}")
        else:
            out.append(f"{k} = {v:.4g}")
    return ", ".join(out)


def format_effect(effect: dict) -> str:
    """One named effect for people: ``ground_effect (mu = 1.9996 ± 0.0021)``."""
    return f"{effect['name']} ({format_params(effect['params'], effect.get('stderr'))})"


def _label(feature: str) -> str:
    unit = FEATURE_UNITS.get(feature)
    return f"{feature} [{unit}]" if unit else feature


def _figure(figsize: tuple[float, float]):
    """A figure drawn by Agg alone (no pyplot: nothing global to close, less to import)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, dpi=PLOT_DPI)
    FigureCanvasAgg(fig)
    return fig


def _save(fig, path: Path) -> None:
    """``path`` as PNG at :data:`PLOT_DPI`, the figure laid out already (``tight_layout``, or
    :func:`~uavturb.gap.plotting.grid_layout`).

    ``tight_layout`` leaves a placeholder layout engine behind, and for any engine ``savefig`` first runs
    a whole draw without rendering (ticks, text extents) before the real one: with the engine unset, one
    draw (the same pixels). zlib level 1: the same pixels, several times faster to write than the default
    level 6, about 10 % larger.
    """
    fig.set_layout_engine(None)
    fig.savefig(path, dpi=PLOT_DPI, pil_kwargs={"compress_level": 1})


def _plot_time(ax, t: np.ndarray, y: np.ndarray, pixels: int, **kw) -> None:
    """``ax.plot(t, y)`` through the rows a raster ``pixels`` wide shows (:func:`column_envelope`)."""
    keep = column_envelope(t, y, COLUMNS_PER_PIXEL * pixels)
    ax.plot(t[keep], y[keep], **kw)


def write_plots(folder: Path, data, baseline_r, baseline_rs, final_r, final_rs, segs, top_driver: str | None,
                heldout_before, heldout_after, surface: tuple | None = None, ahead: FiguresAhead | None = None
                ) -> list[str]:
    """The figures a person needs to believe the report, drawn side by side in processes forked from this one
    (:class:`~uavturb.numerics.processes.ForkedPool`: each figure is Python-bound; a dozen recordings' took 4.5 s
    one after the other, the residual over time 3 s of it); returns their file names, in the report's order.

    ``surface``: ``(curve, fits, named)`` of :func:`plot_surface_curve`, whose figure is drawn with them (none where
    None). ``ahead``: the figures a child started drawing at the analysis's checkpoint (:class:`FiguresAhead`),
    taken where they were drawn from these very objects. A figure a child could not draw is drawn here (its error
    raised here)."""
    import matplotlib.backends.backend_agg  # noqa: F401 - imported once, before the children fork, not in each

    figures: dict[str, Callable[[], str]] = {
        "residual_time": lambda: plot_residual_time(folder, data, baseline_r, baseline_rs, final_rs, segs)}
    if top_driver is not None:
        figures["residual_vs_driver"] = lambda: plot_residual_vs_driver(folder, data, baseline_rs, final_rs,
                                                                        top_driver)
    figures["heldout_fit"] = lambda: plot_heldout_fit(folder, data, heldout_before, heldout_after)
    if surface is not None:
        figures["surface_curve"] = lambda: plot_surface_curve(folder, *surface)
    same = dict(data=data, r0=baseline_r, rs0=baseline_rs, rsf=final_rs, segs=segs, base_ho=heldout_before,
                final_ho=heldout_after)
    coming = ahead.drawing(same) if ahead is not None else ()
    rest = {k: draw for k, draw in figures.items() if k not in coming}
    with ForkedPool(rest) as pool:
        drawn = pool.map(_draw_in_child, rest)
    drawn |= ahead.taken(folder) if coming else {}
    return [drawn[k] if k in drawn else draw() for k, draw in figures.items()]


def _draw_in_child(name: str) -> str:
    """In a child of :func:`write_plots`: the figure ``name`` drawn."""
    return forked_state()[name]()


class FiguresAhead:
    """The figures drawn from what the analysis knows at its checkpoint alone (the residual over time and the held-out
    fit: :attr:`~uavturb.gap.finder.Checkpoint.plots`), drawn in a process forked there while the analysis runs to
    its end: the surface curve and the honest errors keep about one core of two busy (1.7 s on a dozen one-minute
    recordings), and the residual over time is the longest figure (1.6 s there). :func:`write_plots` takes them and
    draws the rest.

    :meth:`start` is ``analyse``'s ``at_checkpoint``. A context manager: on leaving it, a child still drawing is
    stopped and its folder (a temporary one, not the report's) removed. Nothing is drawn ahead where no process can
    be forked; a child that fails leaves its figures to :func:`write_plots`."""

    #: the figures drawn ahead, in the order the child draws them (the longest first)
    NAMES = ("residual_time", "heldout_fit")

    def __init__(self) -> None:
        self._plots: dict | None = None
        self._folder: tempfile.TemporaryDirectory | None = None
        self._started: Started | None = None

    def __enter__(self) -> "FiguresAhead":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def start(self, plots: dict) -> None:
        """Start drawing :data:`NAMES` from ``plots`` (a checkpoint's) in a forked child (one started before is
        stopped first)."""
        self.close()
        if not forking_possible():
            return
        self._plots = plots
        # a child stopped while it writes may leave a file behind the removal: nothing to report then
        self._folder = tempfile.TemporaryDirectory(prefix="uavturb-figures-", ignore_cleanup_errors=True)
        pool = ForkedPool((self.folder, plots), max_processes=1)
        self._started = pool.start(_draw_ahead_in_child, 0)

    def drawing(self, plots: dict) -> tuple[str, ...]:
        """The figures being drawn ahead from ``plots``: :data:`NAMES` where the child started from these very
        objects (the same figures), none otherwise (the child is stopped)."""
        if self._started is None or any(plots[k] is not self._plots.get(k) for k in plots):
            self.close()
            return ()
        return self.NAMES

    def taken(self, folder: Path) -> dict[str, str]:
        """The child waited for, and what it drew moved into ``folder``: ``{name: file name}``; empty where it
        failed (:func:`write_plots` draws those)."""
        files = self._started.result(lambda: []) if self._started is not None else []
        self._started = None
        drawn = {}
        for name, file in zip(self.NAMES, files):
            if (self.folder / file).is_file():
                shutil.move(self.folder / file, Path(folder) / file)
                drawn[name] = file
        self.close()
        return drawn

    @property
    def folder(self) -> Path | None:
        """Where the child draws (a temporary folder); None where nothing is being drawn ahead."""
        return None if self._folder is None else Path(self._folder.name)

    def close(self) -> None:
        """Stop a child still drawing and remove its folder."""
        if self._started is not None:
            self._started.cancel()
            self._started = None
        if self._folder is not None:
            self._folder.cleanup()
            self._folder = None
        self._plots = None


def _draw_ahead_in_child(_: object) -> list[str]:
    """In a child of :meth:`FiguresAhead.start`: the figures :data:`FiguresAhead.NAMES` drawn into its folder."""
    folder, p = forked_state()
    return [plot_residual_time(folder, p["data"], p["r0"], p["rs0"], p["rsf"], p["segs"]),
            plot_heldout_fit(folder, p["data"], p["base_ho"], p["final_ho"])]


@gc_paused
def plot_residual_time(folder: Path, data, baseline_r, baseline_rs, final_rs, segs) -> str:
    """``folder/residual_time.png``: the residual over time with the located segments shaded, per recording x, y
    and z stacked; returns the file name."""
    groups = np.unique(data.group)
    cols, rows = recording_grid(len(groups))
    fig = _figure((PANEL_WIDTH_IN * cols + 1, 7 * rows))
    axes = fig.subplots(3 * rows, cols, squeeze=False)
    px = int(fig.get_figwidth() * PLOT_DPI / cols)  # pixel columns of a panel's cell, more than its axes'
    for c, g in enumerate(groups):
        m = data.group == g
        block = axes[3 * (c // cols):3 * (c // cols) + 3, c % cols]
        for j in range(3):
            ax = block[j]
            if j:
                ax.sharex(block[0])
            _plot_time(ax, data.t[m], baseline_r[m, j], px, lw=0.3, color="0.7", label="residual (nominal model)")
            _plot_time(ax, data.t[m], baseline_rs[m, j], px, lw=1.0, color="tab:blue", label="smoothed")
            _plot_time(ax, data.t[m], final_rs[m, j], px, lw=1.0, color="tab:green", label="after the named effects")
            shade_spans(ax, [(s.t_start, s.t_end) for s in segs if s.group == g and s.axis == AXES[j]],
                        color="tab:red", alpha=0.15, lw=0)
            ax.set_ylabel(f"F_{AXES[j]} [N]")
        block[0].set_title(data.names[g])
        block[-1].set_xlabel("t [s]")
    hide_unused_cells(axes, len(groups), cols, 3)
    axes[0, 0].legend(loc="upper right", fontsize=7)
    title = fig.suptitle("Residual force over time; located mismatch segments shaded")
    grid_layout(fig, axes, title)
    _save(fig, folder / "residual_time.png")
    return "residual_time.png"



@gc_paused
def plot_residual_vs_driver(folder: Path, data, baseline_rs, final_rs, top_driver: str) -> str:
    """``folder/residual_vs_driver.png``: the residual against its driving feature, before and after; returns the
    file name."""
    x = features(data)[top_driver]
    j = int(np.argmax(np.var(baseline_rs, axis=0)))
    fig = _figure((11, 4))
    ax = fig.subplots(1, 2, sharey=True)
    shown = scatter_rows(x, (baseline_rs[:, j], final_rs[:, j]))  # the mean per bin below is of every row
    for a, r, title in ((ax[0], baseline_rs, BEFORE_ALL), (ax[1], final_rs, "after")):
        a.scatter(x[shown], r[shown, j], s=1, alpha=0.3)
        edges = np.unique(np.quantile(x, np.linspace(0, 1, 25)))
        idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)
        cnt = np.maximum(np.bincount(idx), 1)
        a.plot(np.bincount(idx, weights=x) / cnt, np.bincount(idx, weights=r[:, j]) / cnt, "o-",
               color="k", lw=1.5, ms=3, label="mean per quantile bin")
        a.set_title(f"{title}: smoothed F_{AXES[j]}", fontsize=9)
        a.set_xlabel(_label(top_driver))
        a.legend()
    ax[0].set_ylabel(f"F_{AXES[j]} [N]")
    fig.tight_layout()
    _save(fig, folder / "residual_vs_driver.png")
    return "residual_vs_driver.png"


@gc_paused
def plot_heldout_fit(folder: Path, data, heldout_before, heldout_after) -> str:
    """``folder/heldout_fit.png``: the held-out fit before and after, ``|residual|`` on the held-out rows per
    recording over time; returns the file name."""
    hg = heldout_before.group if heldout_before.group is not None else np.zeros(len(heldout_before.err2), int)
    ht = heldout_before.t if heldout_before.t is not None else np.arange(len(hg), dtype=float)
    hgroups = np.unique(hg)
    cols, rows = recording_grid(len(hgroups))
    fig = _figure((PANEL_WIDTH_IN * cols + 1, 3.5 * rows))
    axes = fig.subplots(rows, cols, squeeze=False, sharey=True)
    px = int(fig.get_figwidth() * PLOT_DPI / cols)
    dt = float(np.median(np.diff(data.t)))
    n = max(1, int(round(0.25 / dt)))  # 0.25 s moving RMS
    for c, g in enumerate(hgroups):
        ax = axes[c // cols, c % cols]
        m = hg == g
        order = np.argsort(ht[m])
        for ho, label, color in ((heldout_before, BEFORE_HELDOUT, "tab:blue"), (heldout_after, "after", "tab:green")):
            e2 = ho.err2[m][order]
            rms = np.sqrt(np.convolve(e2, np.ones(n) / n, "same"))
            _plot_time(ax, ht[m][order], rms, px, color=color, lw=1,
                       label=f"{label}: {np.sqrt(np.mean(ho.err2[m])):.3f} N")
        ax.set_title(f"held out: {data.names[int(g)]}")
        ax.set_xlabel("t [s]")
        ax.legend(fontsize=8)
    hide_unused_cells(axes, len(hgroups), cols, 1)
    for ax in axes[:, 0]:
        ax.set_ylabel("|residual|, 0.25 s RMS [N]")
    title = fig.suptitle(f"Held-out fit before and after the named effects (RMSE {heldout_before.rmse:.3f} N → "
                         f"{heldout_after.rmse:.3f} N)")
    grid_layout(fig, axes, title)
    _save(fig, folder / "heldout_fit.png")
    return "heldout_fit.png"


def write_markdown(folder: Path, report: dict, plots: list[str]) -> None:
    """``report.md``: the findings in words, tables and the plots."""
    names = _RecordingNames(report["recordings"])
    L = ["# Sim-to-real gap report", ""]
    L.append(f"Recordings: {', '.join('`' + r + '`' for r in report['recordings'])}  ")
    L.append(f"Simulator effects: {', '.join(report['sim_effects']) or 'none'}  ")
    L.append(f"Protocol: {report['protocol']}; residual from {report['residual_source']}")
    L.append("")
    b, f = report["baseline"], report["final"]
    weight = report.get("facts", {}).get("weight_N")
    share = f", {100 * b['rmse_N'] / weight:.2g} % of the weight" if weight else ""
    L.append(f"**Held-out residual RMSE: {b['heldout_rmse_N']:.4f} N → {f['heldout_rmse_N']:.4f} N** "
             f"(nominal model {b['rmse_N']:.4f} N on all data{share}; sensor noise floor "
             f"{report['noise']['rms_N']:.4f} N).")
    if weight and b["rmse_N"] > NOMINAL_MISS_SHARE * weight:
        L.append(f"\n**The nominal model misses by {100 * b['rmse_N'] / weight:.0f} % of the weight** (real flights "
                 f"leave a few percent): before reading any effect, check vehicle.yaml (mass, rotor order and spins, "
                 f"rotor_speed_scale), the rotor stream's units and rate (What the streams hold) and the rests on the "
                 f"ground (the rows shown in Where the mismatch is).")
    L.append("")
    L += _named_effect_lines(report["effects"], bool(report.get("ambiguous")))
    L += _undecided_lines(report, names)
    L += _surface_curve_lines(report.get("surface_curve"), report.get("height_reference"),
                              report.get("surface_curve_missing"))
    L += _recording_lines(report, names)
    if report["sim_effect_params"]:
        L.append("")
        L.append("## The simulator's own effects, refitted")
        for n, p in report["sim_effect_params"].items():
            L.append(f"- `{n}`: simulator {format_params(p['sim'])}, fitted {format_params(p['fitted'])}")
    L.append("")
    L += _mismatch_lines(report, names)
    if "open_loop" in report:
        ol = report["open_loop"]
        L.append("")
        L.append(f"## Closing the loop\nOpen-loop position error over {ol['horizon_s']} s horizons: "
                 f"{ol['before_m']:.4f} m → {ol['after_m']:.4f} m with the fitted effects.")
    L.append("")
    for p in plots:
        L.append(f"![{p}]({p})")
    (folder / "report.md").write_text("\n".join(L) + "\n")


def _named_effect_lines(effects: list[dict], undecided: bool) -> list[str]:
    """report.md's "Named effects": a table of the named ``effects`` with their held-out gain, then each one's
    explanation, what limits each parameter's error, and what is left open of its law; ``undecided``: whether
    anything was left ambiguous (said where nothing was named)."""
    L = ["## Named effects"]
    if not effects:
        L.append("None: what these flights cannot decide is listed under Undecided." if undecided else
                 "None: no effect of the vocabulary improves the held-out fit beyond what noise explains.")
    else:
        L.append("| effect | parameters (± std. error) | held-out RMSE before → after [N] | z |")
        L.append("|---|---|---|---|")
        for e in effects:
            ps = format_params(e["params"], e["stderr"])
            via = (f" ({e['named_for']['z_heldout']:.1f} for `{e['named_for']['law']}`)" if e.get("named_for")
                   else "")
            L.append(f"| `{e['name']}` | {ps} | {e['heldout_rmse_before_N']:.4f} → {e['heldout_rmse_after_N']:.4f} | "
                     f"{e['z_heldout']:.1f}{via} |")
        L.append("")
        for e in effects:
            L.append(f"- **{e['name']}**: {e['explanation']}")
            for k, b in (e.get("error_budget") or {}).items():
                terms = ", ".join(f"{t.replace('_', ' ')} {v:.3g}" for t, v in b.items()
                                  if t in BUDGET_TERMS and v is not None and np.isfinite(v))
                short = b.get("recordings_too_short", 0)
                left = (f"; {short} recording(s) with too few rows in flight to be fitted alone left out of the "
                        f"spread between recordings" if short else "")
                untested = b.get("recordings_cannot_test", [])
                if untested:
                    why = ("out of the law's reach" if EFFECTS[e["name"]].surface else
                           f"the effect there under {100 * PRACTICAL_SHARE:.1g} % of the weight")
                    left += (f"; {', '.join(untested)} cannot test it on {'its' if len(untested) == 1 else 'their'} "
                             f"own rows ({why}): left out of the spread between recordings")
                share = b.get("largest_block_share")
                if share is not None and share >= ONE_STRETCH_SHARE:
                    left += (f"; one of {TIME_BLOCKS} stretches of the flight in time carries {100 * share:.0f} % of "
                             "what pins it, so its spread between stretches is mostly unmeasured (each stretch "
                             "weighted by what it holds): fly near the surface through more of the flight to "
                             "measure it")
                L.append(f"  - error of {k}: ± {b['stderr']:.3g}, limited by {b['limited_by'].replace('_', ' ')} "
                         f"({terms}){left}")
            if e.get("law_shape_open"):
                o = e["law_shape_open"]
                if o.get("law"):
                    bar = (f"{o['needed']:g} needed to name it instead, but its parameter moves by more than half "
                           f"its value with the heights moved by the height reference's +-1 cm"
                           if o.get("not_pinned_by_heights") else f"{o['needed']:g} needed to name it instead")
                    L.append(f"  - its law is not decided: `{o['law']}` fitted the held-out rows better, by "
                             f"{o['heldout_z_over']:.2g} errors ({bar}), and no "
                             "measured surface curve judged their shapes; between and beyond these flights' heights "
                             "the two may differ by more than the error above. To tell them apart: hover far from the "
                             "floor and at several low heights, a few seconds each")
                else:
                    L.append("  - its shape was not checked: no surface curve was measured, so between and "
                             "beyond these flights' heights another law of the registry may describe the lift better. "
                             "To measure it: hover far from the floor and at several low heights, a few seconds each")
            if e.get("untaken_candidates"):
                L.append("  - its error covers " + ", ".join(
                    f"`{c}` (held-out gain {z:.2g} errors: not taken)" for c, z in e["untaken_candidates"].items())
                    + " fitted beside it: the held-out rows cannot tell how much of the force is theirs")
            if e.get("time_domain"):
                td = e["time_domain"]
                L.append(f"  - named from the measured surface curve; found in time as `{td['name']}` "
                         f"({format_params(td['params'], td.get('stderr'))})")
    return L


def _mismatch_lines(report: dict, names: dict[str, str]) -> list[str]:
    """report.md's "Where the mismatch is" (the located segments, largest first, and their drivers) and
    "Unexplained" (what the named effects leave beyond noise, and a thrust-axis tilt read in it); ``names``: the
    recordings' short names."""
    L = ["## Where the mismatch is"]
    segs = report["mismatch"]["segments"]
    L.append(f"{len(segs)} segment(s) where the nominal model's residual stands out of the noise"
             + (" (largest first):" if segs else "."))
    if segs:
        L.append("")
        L.append("| recording | t start [s] | t end [s] | axis | RMS [N] |")
        L.append("|---|---|---|---|---|")
        for s in sorted(segs, key=lambda s: -s["rms_N"])[:15]:
            L.append(f"| {names[s['recording']]} | {s['t_start']:.2f} | {s['t_end']:.2f} | {s['axis']} | "
                     f"{s['rms_N']:.3f} |")
    L.append("")
    drv = report["mismatch"]["drivers"]
    L.append("Drivers (share of the smoothed residual explained): " +
             (", ".join(f"{d['feature']} {d['score']:.2f} ({d['axis']})" for d in drv) or "none"))
    L.append("")
    u = report["unexplained"]
    tilt = u.get("thrust_axis_tilt")
    L.append(f"## Unexplained\nRMS beyond noise after the named effects: {u['rms_N']:.4f} N; drivers"
             f"{' of what the thrust-axis tilt below leaves' if tilt else ''}: " +
             (", ".join(f"{d['feature']} {d['score']:.2f}" for d in u["drivers"]) or "none"))
    if tilt:
        L.append("")
        L.append(f"Thrust-axis tilt: {_tilts_text(tilt['per_recording'], names)}. It explains "
                 f"{100 * tilt['explains_share']:.0f} % of the horizontal "
                 f"residual (RMS beyond noise left: {tilt['rms_beyond_tilt_N']:.4f} N): {tilt['why']}.")
    return L


class _RecordingNames(dict):
    """``{recording path: short name}`` for report.md (:func:`~uavturb.io.reader.recording_labels`: the folder's
    name, with parents where folders share one); a path not among the report's recordings by its folder's name."""

    def __init__(self, paths: list[str]):
        super().__init__(zip(paths, recording_labels(paths)))

    def __missing__(self, path: str) -> str:
        return Path(path).name


def _tilts_text(per_recording: list[dict], names: dict[str, str]) -> str:
    """``mq_11 1.20 ± 0.0089 deg towards 0 deg (from body +x to +y); ...``: each recording's thrust-axis tilt."""
    return "; ".join(f"{names[e['recording']]} {e['tilt_deg']:.2f} ± {e['stderr_deg']:.2g} deg towards "
                     f"{round(e['azimuth_deg']) + 0} deg (from body +x to +y)" for e in per_recording)


def _surface_curve_lines(curve: dict | None, height: dict | None = None, missing: str | None = None) -> list[str]:
    """The measured surface curve beside the named law, whether the law's shape fits it, and where the heights
    are measured from (``height``: the report's ``height_reference``); without a curve, why (``missing``)."""
    if not curve:
        return ["", "## Measured surface curve", f"Not measured: {missing}."] if missing else []
    plane = ""
    if height:
        z = height["rotor_plane_z_m"]
        where = ("the body origin" if z == 0.0
                 else f"{100 * abs(z):.1f} cm {'above' if z > 0 else 'below'} the body origin")
        plane = f" (rotor_plane_z: {where}, +-{100 * height['uncertainty_m']:.0f} cm in every stated error)"
    L = ["", "## Measured surface curve",
         f"Thrust per rotor speed squared over its value far from the floor (above {curve['far_m']:.2f} m), by the "
         f"rotor plane's height{plane}; law: `{curve['law']}` ({format_params(curve['params'], curve['stderr'])} "
         f"fitted to the curve, chi^2/dof = {curve['chi2_dof']:.2f}). "
         f"{'The law fits the curve' if curve['law_fits'] else 'The law does not fit the curve'}: {curve['why']}",
         ""]
    band = all("law_stderr" in b for b in curve["bins"])
    L += ["| rotor-plane height [m] | samples | measured ratio | ± | law |" + (" law ± |" if band else ""),
          "|---|---|---|---|---|" + ("---|" if band else "")]
    for b in curve["bins"]:
        L.append(f"| {b['d_m']:.3f} | {b['n']} | {b['ratio']:.4f} | {b['stderr']:.4f} | {b['law']:.4f} |"
                 + (f" {b['law_stderr']:.4f} |" if band else ""))
    named = curve.get("named") or {}
    largest = named.get("largest_band")
    if band and largest is not None:
        several = named.get("law") in EFFECTS and len(EFFECTS[named["law"]].params) > 1
        L.append(f"\nLaw ±: how far the named law moves in each bin within its stated errors (each parameter one "
                 f"error either way), up to {100 * largest:.1f} % of thrust"
                 + (": it is known to within 2 % in every bin." if largest <= 0.02 else
                    ": beyond 2 % these flights do not pin the law down at every height.")
                 + (" Each parameter is moved alone: where they trade against each other, together they move the "
                    "law less." if several else ""))
    lo, hi = curve["bins"][0].get("lo_m"), curve["bins"][-1].get("hi_m")
    if lo is not None and hi is not None:
        L.append(f"\nMeasured between {lo:.3f} and {hi:.3f} m (the hover-like samples' rotor-plane heights): the law's "
                 "values nearer the floor or farther from it are its shape carried beyond these flights, not a "
                 "measurement.")
    for alt in curve.get("alternatives", []):
        L.append(f"\nAlternative `{alt['law']}`: {format_params(alt['params'], alt['stderr'])}, chi^2/dof = "
                 f"{alt['chi2_dof']:.2f} ({'fits' if alt['law_fits'] else 'does not fit'}).")
    moved = [b["stderr_thrust_map"] for b in curve["bins"] if "stderr_thrust_map" in b]
    if moved:
        terms = ", ".join(f"{k} ± {v:.2g}" for k, v in curve.get("thrust_map", {}).items() if np.isfinite(v))
        L.append(f"\n**Commanded speeds' offset**: the ratios are read on commanded rotor speeds whose offset is "
                 f"not pinned (below, Thrust map): across the offsets left open each bin's ratio moves by up to "
                 f"± {max(moved):.3f} beside its ± above, and the law's values on the curve by "
                 f"{terms or 'an unknown amount'} (in their stated errors).")
    offset = (height or {}).get("offset_read_from_curve")
    if offset:
        L.append(f"\n**Heights off?** {offset['why']}.")
    for note in curve.get("notes", []):
        L.append(f"\nNote: {note}")
    if curve.get("not_named"):
        L.append(f"\n**Not named**: {curve['not_named']}.")
    if height and height.get("note"):
        L.append(f"\n**Height reference**: {height['note']}")
    return L


def _dropout_lines(gaps: list[dict], names: dict[str, str]) -> list[str]:
    """One line per recording and stream with dropouts: how many, the longest, and the time they take."""
    by: dict[tuple[str, str], list[dict]] = {}
    for g in gaps:
        by.setdefault((names[g["recording"]], Path(g["stream"]).parent.name), []).append(g)
    lines = []
    for (rec, stream), gs in by.items():
        long = max(gs, key=lambda g: g["t_end"] - g["t_start"])
        span = f"{long['t_end'] - long['t_start']:.2f} s ({long['t_start']:.2f}-{long['t_end']:.2f} s)"
        total = sum(g["t_end"] - g["t_start"] for g in gs)
        desc = f"{len(gs)} stretches, {total:.2f} s in all (the longest {span})" if len(gs) > 1 else span
        lines.append(f"- **Dropout**: {rec}/{stream} has no sample for {desc}: the rows there, and within a "
                     f"derivative window of them, are left out of every fit, not interpolated across")
    return lines


def _delay_line(d: dict, names: dict[str, str]) -> str:
    """One late stream: its delay, whether it was taken out, and what is still uncertain of it."""
    line = f"- {names[d.get('recording', '')]}: {d['describe']}"
    line += " (taken out of the timestamps" if d.get("applied") else " (not taken out"
    lo, hi = d.get("uncertain_s") or (0.0, 0.0)
    where = (f"the delay taken out may be off by {1e3 * lo:+.0f} to {1e3 * hi:+.0f} ms" if d.get("applied") else
             f"the true delay may be anywhere from {1e3 * lo:.0f} to {1e3 * hi:.0f} ms")
    return line + f"; {where}, and every named effect was refitted over that range: the rotor timing term of its error)"


def _recording_lines(report: dict, names: dict[str, str]) -> list[str]:
    """Ground contact left out, what each stream holds, late streams, thrust levels."""
    L: list[str] = []
    if report.get("ground_contact"):
        L += ["", "## Left out: ground contact"]
        L += [f"- {names[c['recording']]} {c['t_start']:.2f}-{c['t_end']:.2f} s: {c['why']}"
              for c in report["ground_contact"]]
    landed = (report.get("height_reference") or {}).get("landed_heights")
    if landed:
        entries = landed["recordings"]
        said = LandedHeights.from_report(landed).sentence([names[e["recording"]] for e in entries])
        L += ["", f"**Landed heights**: {said}."]
    streams = report.get("streams") or {}
    if streams:
        L += ["", "## What the streams hold"] + [f"- {line}" for line in streams.get("streams", [])]
        rated = [f"`{e['name']}`" for e in report.get("effects", []) if EFFECTS[e["name"]].surface
                 and any("stream_rate" in b for b in (e.get("error_budget") or {}).values())]
        L += [f"- **Too slow**: {why}" + (f"; {', '.join(rated)} named all the same, its error carrying what thinning "
                                          "these updates to every other one changes (stream rate)"
                                          if rated and "a surface effect" in why else "")
              for why in streams.get("stream_limits", [])]
        L += [_delay_line(d, names) for d in streams.get("delays", [])]
        L += _dropout_lines(streams.get("dropouts", []), names)
        L += _torque_lag_line((report.get("facts") or {}).get("torque_lag"))
    nominal = report.get("nominal", {})
    if nominal.get("thrust_level_note"):
        L += ["", f"Thrust levels: {nominal['thrust_level_note']}."]
    terms = nominal.get("thrust_coefficient_stderr_terms")
    if terms and nominal.get("thrust_coefficient"):
        k, se = nominal["thrust_coefficient"], nominal["thrust_coefficient_stderr"]
        limit = {"sample": "sample noise", "between_recordings": "the spread between recordings",
                 "undecided_thrust_law": "the law scaling the thrust left undecided beside it (what it moves by with "
                                         "the law fitted)",
                 "rotor_resolution": "the rotor speeds' rounding (a steady hover keeps it)",
                 }[max(terms, key=lambda t: np.nan_to_num(terms[t], nan=-1.0))]
        sag = next((e for e in report.get("effects", []) if e["name"] == "battery_sag"), None)
        when = (f" It is the value at each recording's start: with `battery_sag` named (s = {sag['params']['s']:.3g} "
                "/s) the thrust per rotor speed squared is k_T (1 - s t), lower later in the flight, as `identify`, "
                "which fits one constant, reads it" if sag else "")
        L += [f"Thrust coefficient k_T = {k:.4g} ± {se:.2g} N/(rad/s)^2 ({100 * se / k:.2g} %, limited by "
              f"{limit}).{when}"]
        yaml_k = nominal.get("thrust_coefficient_vehicle_yaml")
        if yaml_k:
            off = 100 * (k / yaml_k - 1)
            L[-1] += (f" vehicle.yaml states {yaml_k:.4g} ({off:+.1f} %" + (
                "; the flights' own value is used: a thrust coefficient that far off, or rotor speeds in other "
                "units, changes every law in rotor speed)." if abs(off) > 100 * YAML_THRUST_DIFFERS else ")."))
    if nominal.get("rotor_speed_offset"):
        L += ["", f"Thrust map: {nominal['rotor_speed_offset']['note']}."]
    return L


def _undecided_lines(report: dict, names: dict[str, str]) -> list[str]:
    """What these recordings cannot decide, fits outside physical ranges, untestable effects."""
    L: list[str] = []
    if report.get("ambiguous"):
        L += ["", "## Undecided (ambiguous)",
              "These recordings cannot tell the following apart; nothing here is a discovery."]
        for a in report["ambiguous"]:
            L.append(f"- **{' vs '.join(a['candidates'])}**: {a['why']}. To separate them: {a['to_separate']}.")
            if a.get("per_recording"):
                L.append(f"  - read as a tilt, each recording alone: {_tilts_text(a['per_recording'], names)}")
    if report.get("rejected"):
        L += ["", "## Fitted, not discoveries"]
        for r in report["rejected"]:
            reason = REJECTION_REASONS.get(r.get("reason", ""))
            L.append(f"- `{r['name']}`{f' ({reason})' if reason else ''}: {r['why']}.")
    if report.get("not_testable"):
        L += ["", "## Not testable on these flights"]
        reasons: dict[tuple[str, str], list[str]] = {}  # effects that share why and what would test them: one line
        for r in report["not_testable"]:
            reasons.setdefault((r["why"], r["to_separate"]), []).append(f"`{r['name']}`")
        for (why, to_test), names in reasons.items():
            L.append(f"- {', '.join(names)}: {why}. To test {'it' if len(names) == 1 else 'them'}: {to_test}.")
    L += _not_named_lines(report)
    nominal = report.get("nominal", {})
    if nominal.get("accel_bias_note"):
        L += ["", "Accelerometer bias: " + nominal["accel_bias_note"] + "."]
    return L


def _not_named_lines(report: dict) -> list[str]:
    """Every candidate tried that is neither named nor undecided, outside its range or untestable: its held-out
    gain at the last step it was tried at, whether it was chosen and dropped, and whether the named effects' errors
    carry it (``untaken_candidates``), with the flight that would show it."""
    said = ({e["name"] for e in report.get("effects", [])} | {r["name"] for r in report.get("rejected", [])}
            | {r["name"] for r in report.get("not_testable", [])} | set(report.get("sim_effects", []))
            | {c for a in report.get("ambiguous", []) for c in a["candidates"]})
    carried = {c for e in report.get("effects", []) for c in e.get("untaken_candidates", {})}
    surfaces = {EFFECTS[n].surface for n in said if n in EFFECTS and EFFECTS[n].surface}
    L: list[str] = []
    for name, tried in (report.get("candidates_tried") or {}).items():
        last = last_step(tried)
        rounded = _beaten_within_rounding(tried)
        if name not in said and rounded is not None:
            step, standard, z = rounded
            L.append(f"- `{name}`: fitted the held-out rows better than `{standard}` by {z:.2g} errors at step "
                     f"{step}, but by less than the rotor speeds' rounding can fake along the thrust (a hover holds "
                     f"one rounded value while the law's lift moves): `{standard}` is named, as effects.md's standard "
                     f"law; the measured surface curve compares their shapes.")
            continue
        if name not in said and "swapped_out_z" in tried:
            L.append(f"- `{name}`: taken first for what it gained alone, but another law of its surface with a "
                     f"thrust-scaling law beside it fitted the held-out rows better by {tried['swapped_out_z']:.2g} "
                     "errors: the selection was made again without it.")
            continue
        if name in said or name not in EFFECTS or last is None or EFFECTS[name].surface in surfaces:
            continue  # a surface law beside one said of its surface: the measured surface curve compares them
        text = f"- `{name}`: held-out gain {last[1]:.2g} errors at step {last[0]} ({Z_IMPROVE:g} needed)"
        if "dropped_z" in tried:
            text += (f"; chosen, then dropped: without it the held-out fit was worse by only "
                     f"{tried['dropped_z']:.2g} errors")
        partner = next((k[len("dropped_with_"):] for k in tried if k.startswith("dropped_with_")), None)
        if partner is not None:
            text += (f"; chosen together with `{partner}` (neither gained enough alone), then dropped with it when "
                     f"`{partner}` was not named (see above)")
        if name in carried:
            text += "; fitted beside the named effects, it is in their errors (untaken candidate)"
        lag = (report.get("facts") or {}).get("torque_lag")
        if name == "motor_lag" and lag and lag.get("decisive"):
            text += (f"; the roll and pitch torques lag the commands by {1e3 * lag['tau_s']:.0f} ± "
                     f"{1e3 * lag['stderr_s']:.0f} ms (What the streams hold): the motors lag, though the thrust's "
                     "held-out rows could not show it")
        beside = _passed_beside_unphysical(tried)
        if beside is not None:
            partner, step, z = beside
            text += (f"; with `{partner}` beside it the held-out fit improved by {z:.2g} errors at step {step}, but "
                     f"`{partner}`'s fit lies outside its physical range (see above): neither is named, a fit outside "
                     f"its range being no discovery")
        manoeuvre = _surface_flown(report, name) or EFFECTS[name].manoeuvre
        L.append(text + (f". To show it: {manoeuvre}." if manoeuvre else "."))
    return (["", "## Tried, not named",
             "Each candidate the data did not support, with what it gained on the held-out rows."] + L) if L else []


def _beaten_within_rounding(tried: dict[str, float]) -> tuple[int, str, float] | None:
    """``(step, standard law, held-out z over it)`` where an alternative law beat its standard law on the held-out
    rows by less than the rounding floor (``step<k>_over_<law>_below_rounding_floor``, selection's
    ``_standard_law``), at the last such step; None where it never did."""
    found = None
    for key in tried:
        if key.startswith("step") and key.endswith("_below_rounding_floor") and "_over_" in key:
            step = int(key[4:key.index("_")])
            standard = key[key.index("_over_") + len("_over_"):-len("_below_rounding_floor")]
            z = tried.get(f"step{step}_z_over_{standard}")
            if z is not None and (found is None or step > found[0]):
                found = (step, standard, float(z))
    return found


def _torque_lag_line(lag: dict | None) -> list[str]:
    """The commanded rotor speeds' timing against the torques they make (``facts.torque_lag``), or nothing."""
    if not lag or lag.get("tau_s") is None:
        return []
    se = lag.get("stderr_s")
    error = f" ± {1e3 * se:.0f}" if se is not None and np.isfinite(se) else ""
    said = (f"the roll and pitch torques line up with the angular acceleration with the commands lagged by "
            f"{1e3 * lag['tau_s']:.0f}{error} ms (correlation {lag['correlation']:.2f}, against "
            f"{lag['correlation_at_zero']:.2f} as recorded)")
    how = ("the motors' own lag" if lag["decisive"] else "no lag the torques can tell from none")
    return [f"- **Commanded rotor speeds**: {said}: {how}."]


def _passed_beside_unphysical(tried: dict[str, float]) -> tuple[str, int, float] | None:
    """``(partner, step, held-out z)`` where a candidate passed a selection step only together with a partner whose
    fit lay outside its physical range (``step<k>_passed_with_unphysical_<partner>``, the pair's z under
    ``step<k>_z_with_<partner>``), the last such step; None otherwise."""
    found = [(int(m.group(1)), m.group(2)) for k in tried
             if (m := re.fullmatch(r"step(\d+)_passed_with_unphysical_(\w+)", k))]
    if not found:
        return None
    step, partner = max(found)
    return partner, step, float(tried.get(f"step{step}_z_with_{partner}", float("nan")))


#: m, a rotor plane that came this near the floor flew what a ground law's test asks (its manoeuvre); Hz, a stream
#: updating slower than this thins what the held-out rows hold
FLOWN_NEAR_FLOOR_M, SLOW_STREAM_HZ = 0.5, 20.0


def _surface_flown(report: dict, name: str) -> str | None:
    """What would show the ground law ``name`` where the flights flew its manoeuvre already (their rotor plane came
    within :data:`FLOWN_NEAR_FLOOR_M` of the floor): more held-out rows near it, and faster streams where one updates
    slowly; None otherwise (the law's own manoeuvre is the advice). A blind probe's ladders of 1.5-8 rotor radii, its
    ESC speeds at 3 Hz, had been told to "hover over the floor at several heights"."""
    near = (report.get("facts") or {}).get("d_down_min_m")
    if EFFECTS[name].surface != "d_down" or near is None or not near <= FLOWN_NEAR_FLOOR_M:
        return None
    hz = (report.get("streams") or {}).get("slowest_update_hz")
    slow = hz is not None and np.isfinite(hz) and hz < SLOW_STREAM_HZ
    return (f"these flights came within {near:.2f} m of the floor; what the held-out rows ({report.get('protocol')}) "
            "hold near it was too little to test it: longer hovers near it, or more recordings"
            + (f", or a faster stream than the slowest here ({hz:.2g} Hz updates)" if slow else ""))


def write_json(folder: Path, report: dict) -> None:
    """``report.json``: strict JSON (a NaN or infinite number is written as ``null``)."""
    (folder / "report.json").write_text(dumps_strict(report, indent=2))


@gc_paused
def plot_surface_curve(folder: Path, curve: SurfaceCurve, fits: dict[str, LawFit],
                       named: tuple[str, Callable[[np.ndarray], np.ndarray]] | None = None) -> str:
    """``folder/surface_curve.png``: measured ratio against rotor-plane height with error bars and counts,
    each law fitted to it, and ``named`` (``(label, d [m] -> ratio)``: the law the report names, at its values)
    drawn bold; returns the file name."""
    name = "surface_curve.png"
    _save(surface_figure(curve, fits, named), Path(folder) / name)
    return name


def surface_figure(curve: SurfaceCurve, fits: dict[str, LawFit],
                   named: tuple[str, Callable[[np.ndarray], np.ndarray]] | None = None):
    """The matplotlib figure of :func:`plot_surface_curve` (Agg)."""
    d, y, se = curve.columns()
    fig = _figure((7, 4.5))
    ax = fig.subplots()
    ax.errorbar(d, y, yerr=se, fmt="o", color="k", ms=4, capsize=3, label="measured (± 1 standard error)")
    for x, yy, b in zip(d, y, curve.bins):
        ax.annotate(f"n={b.n}", (x, yy), textcoords="offset points", xytext=(0, 8), ha="center", fontsize=7)
    if len(d):
        grid = np.linspace(min(b.lo for b in curve.bins), max(b.hi for b in curve.bins), 300)
        for name, lf in fits.items():
            values = ", ".join(f"{k} = {v:.3g}" for k, v in lf.params.items())
            ax.plot(grid, lf.evaluate(grid), lw=1.2, label=f"{name} fitted to the curve: {values}, "
                                                            f"chi²/dof = {lf.chi2_dof:.2f}")
        if named is not None:
            ax.plot(grid, named[1](grid), color="k", lw=2.2, ls="--", label=named[0])
    ax.axhline(1.0, color="0.6", lw=0.8, ls="--")
    ax.set_xlabel("rotor-plane height over the ground d [m]")
    ax.set_ylabel("thrust ratio T_IGE / T_OGE [-]")
    ax.set_title("Measured ground-effect curve and surface laws")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig
