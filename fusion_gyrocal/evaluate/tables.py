"""The comparison's results as tables: :class:`Comparison` (terminal, Markdown, CSV) and :class:`SnrSweep`.

A :class:`Comparison` holds the per-run records of every estimator on the same data (one recording
or the Monte Carlo runs of a scenario, :mod:`fusion_gyrocal.evaluate.montecarlo`) and summarises
them per estimator in a :class:`Row`: the first run's estimate, the RMSE against the truth (the
paper's metrics, Eq. 37-38), its ratio to the Cramer-Rao bound
(:func:`fusion_gyrocal.evaluate.scenarios.scenario_bound`) and the time per solve. It renders as a
terminal table (:meth:`Comparison.print`), Markdown (:meth:`Comparison.to_markdown`) and CSV
(:meth:`Comparison.to_csv`). An :class:`SnrSweep` is one comparison per SNR factor with the fitted
log-log slopes of RMSE versus SNR (:meth:`SnrSweep.slopes`, the paper finds -1).
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from .. import lie
from ..errors import InputError
from .registry import REGISTRY

__all__ = ["Row", "Comparison", "Slope", "SnrSweep"]


@dataclass(frozen=True)
class Row:
    """One estimator's line of a :class:`Comparison` table.

    Errors are RMSE over the successful runs (rad for rotation, fraction for scales, Eq. 37-38);
    bounds are the root mean square of the per-run Cramer-Rao bounds over the same runs (rotation:
    including the skew prediction of Appendix D); ``seconds`` is the median time per solve.
    The estimate columns are those of the first run; ``rotvec_deg`` is the canonical rotation
    vector of its ``R_1_2`` (:func:`fusion_gyrocal.lie.canonical_rotvec`: angle in [0, 180] deg, a
    unique sign at 180 deg), so the same rotation reads the same in every row.
    """

    estimator: str
    description: str
    note: str
    runs: int
    failures: int
    rotvec_deg: np.ndarray
    scale_1: np.ndarray
    scale_2: np.ndarray
    rotation_rmse: float
    rotation_bound: float
    scale_rmse: float
    scale_bound: float
    seconds: float

    @property
    def rotation_ratio(self) -> float:
        return self.rotation_rmse / self.rotation_bound

    @property
    def scale_ratio(self) -> float:
        return self.scale_rmse / self.scale_bound


def _first_line(text: str, width: int = 160) -> str:
    line = text.strip().splitlines()[0] if text.strip() else ""
    return line if len(line) <= width else line[:width - 3] + "..."


def _rms(x) -> float:
    x = np.asarray(x, dtype=float)
    return float(np.sqrt(np.mean(x**2))) if x.size else float("nan")


def _row(k: int, name: str, records) -> Row:
    ests = [r.estimates[k] for r in records]
    ok = [e.ok for e in ests]
    first = ests[0]
    failures = len(ests) - int(np.sum(ok))
    note = "" if failures == 0 else _first_line(next(e.error for e in ests if not e.ok))
    rot = np.array([r.rotation_error[k] for r in records])
    sca = np.array([r.scale_error[k] for r in records])
    has_truth = records[0].bound is not None
    rb = np.array([r.bound.rotation_expected if has_truth else np.nan for r in records])
    sb = np.array([r.bound.scale if has_truth else np.nan for r in records])
    r_sel, s_sel = np.isfinite(rot), np.isfinite(sca)
    nan = float("nan")
    secs = np.array([e.seconds for e in ests if e.ok])
    return Row(
        estimator=name, description=REGISTRY[name].description, note=note, runs=int(np.sum(ok)), failures=failures,
        rotvec_deg=np.rad2deg(lie.canonical_rotvec(lie.log(first.R_1_2))) if first.ok else np.full(3, nan),
        scale_1=first.scale_1, scale_2=first.scale_2,
        rotation_rmse=_rms(rot[r_sel]) if r_sel.any() else nan,
        rotation_bound=_rms(rb[r_sel]) if r_sel.any() else nan,
        scale_rmse=_rms(sca[s_sel]) if s_sel.any() else nan,
        scale_bound=_rms(sb[s_sel]) if s_sel.any() else nan,
        seconds=float(np.median(secs)) if secs.size else nan)


_CSV_COLUMNS = ("estimator", "runs", "failures", "rotvec_x_deg", "rotvec_y_deg", "rotvec_z_deg",
                "scale_1_x", "scale_1_y", "scale_1_z", "scale_2_x", "scale_2_y", "scale_2_z",
                "rotation_rmse_rad", "rotation_bound_rad", "rotation_ratio", "scale_rmse", "scale_bound",
                "scale_ratio", "seconds_per_solve", "note")


@dataclass(frozen=True)
class Comparison:
    """Every estimator on the same data: one recording or the Monte Carlo runs of a scenario.

    Attributes
    ----------
    source : str
        Scenario name, or ``"recording"``.
    description : str
        What the data are.
    estimators : tuple of str
        Estimator names, in row order.
    records : tuple of RunRecord
        Per-run results (one for a recording).
    """

    source: str
    description: str
    estimators: tuple
    records: tuple = field(repr=False)

    @property
    def has_truth(self) -> bool:
        return self.records[0].bound is not None

    @property
    def snr(self) -> float:
        """Mean SNR (Eq. 36) over the runs (NaN for a recording)."""
        return float(np.mean([r.snr for r in self.records]))

    @cached_property
    def rows(self) -> tuple:
        """One :class:`Row` per estimator."""
        return tuple(_row(k, name, self.records) for k, name in enumerate(self.estimators))

    def bound(self, metric: str) -> float:
        """Root-mean-square Cramer-Rao bound over all runs: ``"rotation"`` (rad, with the skew
        prediction of Appendix D) or ``"scale"`` (fraction); NaN without truth."""
        if not self.has_truth:
            return float("nan")
        if metric == "rotation":
            return _rms([r.bound.rotation_expected for r in self.records])
        return _rms([r.bound.scale for r in self.records])

    def row(self, estimator: str) -> Row:
        for r in self.rows:
            if r.estimator == estimator:
                return r
        raise InputError(f"estimator: expected one of {self.estimators}, got {estimator!r}")

    # ---------------------------------------------------------------- formats
    def _title(self) -> str:
        runs = len(self.records)
        head = f"{self.source}: {self.description}"
        if self.has_truth:
            head += f" | {runs} run{'s' if runs > 1 else ''}, SNR {self.snr:.4g}"
        return head

    @property
    def _show_estimates(self) -> bool:
        return len(self.records) == 1 or not self.has_truth

    def _tables(self) -> list[tuple[str, list[str], list[list[str]]]]:
        """``(caption, headers, rows)`` of the estimate table and the accuracy table (human units)."""
        def f(x, fmt):
            return "-" if not np.isfinite(x) else format(x, fmt)

        def vec(v, fmt):
            return "-" if not np.isfinite(v).all() else " ".join(format(x, fmt) for x in v)

        rows = self.rows
        out = []
        if self._show_estimates:
            what = "estimates" if len(self.records) == 1 else "estimates of run 1"
            out.append((what, ["estimator", "rotvec R_1_2 [deg]", "scale_1", "scale_2", "ms / solve"],
                        [[r.estimator, vec(r.rotvec_deg, ".4f"), vec(r.scale_1, ".5f"), vec(r.scale_2, ".5f"),
                          f(r.seconds * 1e3, ".3g")] for r in rows]))
        if self.has_truth:
            err = "error" if len(self.records) == 1 else "RMSE"
            out.append(("errors against the truth (Eq. 37-38) and their ratio to the Cramer-Rao bound",
                        ["estimator", f"rot {err} [mdeg]", "rot / bound", f"scale {err} [%]", "scale / bound",
                         "ms / solve", "failed"],
                        [[r.estimator, f(np.rad2deg(r.rotation_rmse) * 1e3, ".4g"), f(r.rotation_ratio, ".3f"),
                          f(r.scale_rmse * 100, ".4g"), f(r.scale_ratio, ".3f"), f(r.seconds * 1e3, ".3g"),
                          f"{r.failures}/{r.runs + r.failures}" if r.failures else "0"] for r in rows]))
        return out

    def _footer(self) -> list[str]:
        lines = []
        if self.has_truth:
            rb, sb = self.bound("rotation"), self.bound("scale")
            lines.append(f"Cramer-Rao bound (at the truth, true signal): rotation {np.rad2deg(rb) * 1e3:.4g} mdeg, "
                         f"scales {sb * 100:.4g} %")
        lines += [f"{r.estimator}: {r.note}" for r in self.rows if r.note]
        return lines

    def to_markdown(self) -> str:
        """The tables as GitHub Markdown (title, estimate and/or accuracy table, bound and notes)."""
        lines = [f"**{self._title()}**"]
        for caption, headers, rows in self._tables():
            lines += ["", f"*{caption}*", "", "| " + " | ".join(headers) + " |",
                      "|" + "|".join("---" if i == 0 else "---:" for i in range(len(headers))) + "|"]
            lines += ["| " + " | ".join(c.replace("|", "/") for c in row) + " |" for row in rows]
        foot = self._footer()
        if foot:
            lines += [""] + [f"- {x}" for x in foot]
        return "\n".join(lines) + "\n"

    def to_csv(self) -> str:
        """The table as CSV in library units (rad, fraction, seconds), one line per estimator."""
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(_CSV_COLUMNS)
        for r in self.rows:
            w.writerow([r.estimator, r.runs, r.failures, *(repr(float(v)) for v in r.rotvec_deg),
                        *(repr(float(v)) for v in np.concatenate([r.scale_1, r.scale_2])),
                        *(repr(float(v)) for v in (r.rotation_rmse, r.rotation_bound, r.rotation_ratio,
                                                   r.scale_rmse, r.scale_bound, r.scale_ratio, r.seconds)),
                        r.note])
        return buf.getvalue()

    def rich_tables(self) -> list:
        """The tables as :class:`rich.table.Table` objects."""
        from rich.markup import escape
        from rich.table import Table
        out = []
        for k, (caption, headers, rows) in enumerate(self._tables()):
            t = Table(title=escape(self._title()) if k == 0 else None, caption=escape(caption))
            for i, h in enumerate(headers):
                t.add_column(escape(h), justify="left" if i == 0 else "right", no_wrap=i > 0)
            for row in rows:
                t.add_row(*(escape(c) for c in row))
            out.append(t)
        return out

    def print(self, console=None) -> None:
        """Print the tables, the bound and the notes to the terminal (``rich``)."""
        import sys

        from rich.console import Console
        if console is None:
            console = Console(width=None if sys.stdout.isatty() else 160)
        for t in self.rich_tables():
            console.print(t)
        for line in self._footer():
            console.print(line, highlight=False, markup=False)


@dataclass(frozen=True)
class Slope:
    """Fitted log-log slope of RMSE versus SNR for one estimator (NaN where not defined)."""

    estimator: str
    rotation: float
    scale: float


@dataclass(frozen=True)
class SnrSweep:
    """A scenario at several SNR factors (the paper's Section V sweep).

    Attributes
    ----------
    scenario : str
        Base scenario name.
    via : str
        How the SNR was scaled (``"rate"``, ``"noise"``, ``"samples"``).
    factors : tuple of float
    comparisons : tuple of Comparison
        One per factor.
    """

    scenario: str
    via: str
    factors: tuple
    comparisons: tuple = field(repr=False)

    @property
    def estimators(self) -> tuple:
        return self.comparisons[0].estimators

    @property
    def snr(self) -> np.ndarray:
        return np.array([c.snr for c in self.comparisons])

    def rmse(self, estimator: str, metric: str) -> np.ndarray:
        """RMSE per SNR point of ``metric`` (``"rotation"``, rad, or ``"scale"``, fraction)."""
        attr = {"rotation": "rotation_rmse", "scale": "scale_rmse"}[metric]
        return np.array([getattr(c.row(estimator), attr) for c in self.comparisons])

    def bound(self, metric: str) -> np.ndarray:
        """Root-mean-square Cramer-Rao bound per SNR point (all runs, :meth:`Comparison.bound`)."""
        return np.array([c.bound(metric) for c in self.comparisons])

    def slopes(self) -> tuple:
        """Least-squares slope of ``log RMSE`` against ``log SNR`` per estimator (-1 is the paper's finding)."""
        x = np.log(self.snr)
        out = []
        for name in self.estimators:
            s = []
            for metric in ("rotation", "scale"):
                y = np.log(self.rmse(name, metric))
                ok = np.isfinite(y)
                s.append(float(np.polyfit(x[ok], y[ok], 1)[0]) if ok.sum() >= 2 else float("nan"))
            out.append(Slope(name, *s))
        return tuple(out)

    def bound_slopes(self) -> tuple[float, float]:
        x = np.log(self.snr)
        return tuple(float(np.polyfit(x, np.log(self.bound(m)), 1)[0]) for m in ("rotation", "scale"))
