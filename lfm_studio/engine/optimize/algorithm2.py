"""Thesis Algorithm 2, MLA grid-coordinate generation: a greedy search over merged lenslet cells.

The thesis' pseudo-code (section 5.1.2), with ``T`` the lenslet list::

    M <- K / d_min                                  # cells per side
    T_current <- all minimum lenslets; best <- score(concat(T_current))
    for d in range(1, M):                           # aperture sizes, in cells
        for i in range(M - d + 1):                  # positions along x
            for j in range(M - d + 1):              # positions along y
                if !is_symmetric and is_conflict((i, j), d, last_state):
                    T_new = merge((i, j), d, T_last)
                else:
                    T_new = merge((i, j), d, T)
                if score(concat(T_new)) beats best: T_last = T_current, best = score(...)
    return best

What is implemented, and the choices where the pseudo-code is ambiguous
-----------------------------------------------------------------------
- ``score`` replaces ``Reconstruct(concat(T))``: it receives the candidate's
  :class:`Design` (whose MLA the engine turns into a phase mask with
  :func:`~lfm_studio.engine.optics.mla.mla_transmission`, the general form of Algorithm 1;
  :mod:`.algorithm1` is the literal one and is tested to agree). Higher is better
  (``direction="maximize"``) unless ``direction="minimize"``. Acceptance needs a strict
  improvement, so ties keep the earlier (smaller) layout.
- Line 14 assigns ``T_last = T_current``; the pseudo-code never writes ``T_current``.
  We read it as the usual greedy update: on improvement ``T_last <- T_current`` and
  ``T_current <- T_new``; ``T`` in line 11 is ``T_current``.
- ``merge((i, j), d, T)``: the ``d x d`` block at ``(i, j)`` (with its symmetric images)
  absorbs every lenslet of ``T`` lying wholly inside it (:func:`.mla_cells.merge`).
- ``is_conflict``: the block cuts through a lenslet of the "last state", read as the
  current layout ``T_current``, without containing it. Read literally, lines 8-9 then retry the merge on ``T_last`` (the layout before
  the last accepted merge), i.e. the candidate competes as a *replacement* of the last
  merge; this retry happens only without symmetry (``!is_symmetric``), as written. If
  the merge still conflicts (or a symmetric candidate conflicts) it is infeasible:
  recorded with its reason, not scored.
- ``range(1, M)`` is kept as the default sizes (1 .. M - 1; size 1 changes nothing: its
  positions inside the pupil are skipped, those outside recorded as infeasible). Pass ``sizes=range(1, M + 1)`` to also try one lenslet over the whole
  grid. Loop order is the thesis' (size, then x, then y), so runs are deterministic.
- A block whose lenslet leaves the pupil, a layout the design checks refuse
  (:class:`DesignError`) and a score that raises ``ValueError`` or is not finite are
  infeasible candidates with a named reason; a candidate identical to a layout already
  scored is not scored again (the score is deterministic).
- The thesis returns ``current_best``; its stated output is the lenslet list. We return
  both, with the best design (:class:`Algorithm2Result`).

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from lfm_studio.engine.design import Design, DesignError
from lfm_studio.engine.optimize.mla_cells import Block, MLAPlane, check_symmetry, merge, orbit
from lfm_studio.engine.progress import CancelToken, ProgressCallback, checkpoint

Score = Callable[[Design], float]


@dataclass(frozen=True)
class LayoutTrial:
    """One step of Algorithm 2: a candidate layout it considered, as passed to ``record``.

    (Not to be confused with :class:`~.candidate.Candidate`, a design being simulated and
    scored; a stored study keeps each step as an
    :class:`~.evaluate.EvaluationRecord`-format trial, see :mod:`.algorithm2_study`.)

    Attributes
    ----------
    index : int
        Order of consideration (0 = the initial all-minimum layout).
    params : dict
        ``{"size": d, "i": i, "j": j, "base": "current" | "last" | "initial"}``: the block
        tried (cells) and which layout it was merged into.
    blocks : tuple of Block
        The candidate layout (empty when the merge was refused: outside the pupil or a conflict).
    score : float or None
        The score (None when infeasible).
    design : Design or None
        The candidate design (None when it could not be built).
    reason : str
        Why the candidate is infeasible ('' when it was scored).
    accepted : bool
        True when it improved the best score and became the current layout.
    seconds : float
        Wall time spent building and scoring it.
    warnings : tuple of str
        Warnings raised while building and scoring it (e.g. overlapping sub-images); they
        are caught and kept here rather than shown once per candidate.
    reused : bool
        True when its score (or reason) came from ``lookup`` (a stored study), not from scoring.
    """

    index: int
    params: dict
    blocks: tuple[Block, ...]
    score: float | None
    design: Design | None
    reason: str
    accepted: bool
    seconds: float
    warnings: tuple[str, ...] = ()
    reused: bool = False


Lookup = Callable[[tuple[Block, ...]], "tuple[float | None, str] | None"]
"""``lookup(layout)``: the stored ``(score, reason)`` of a layout scored before, or None."""


@dataclass(frozen=True)
class Algorithm2Result:
    """The best layout found: blocks, design and score, and how many candidates were scored.

    ``score`` is the best score (``-inf`` / ``inf`` for maximize / minimize when no
    layout was feasible; ``design`` is then None); ``history`` lists the accepted scores.
    Every layout considered is counted once in ``scored`` (a score from this run), ``infeasible``
    (refused in this run: by the layout checks, the design checks, a constraint or the
    objective) or ``reused`` (its result, score or refusal, taken from ``lookup``): the three add
    up to :attr:`considered`. ``evaluated`` counts the layouts built and passed to the score in
    this run: the scored ones and those the score then refused (also in ``infeasible``).
    """

    blocks: tuple[Block, ...]
    design: Design | None
    score: float
    evaluated: int
    infeasible: int
    history: tuple[float, ...] = field(default=())
    reused: int = 0
    scored: int = 0

    @property
    def considered(self) -> int:
        """Layouts considered in this run: ``scored + infeasible + reused``."""
        return self.scored + self.infeasible + self.reused

    def counts_text(self, study: bool = True) -> str:
        """The counts in words, e.g. ``"26 layouts: 1 scored now, 25 infeasible (5 refused after
        building), 0 from the study"`` (``study=False``: without the last part, for a run without one)."""
        after = self.evaluated - self.scored
        built = f" ({after} refused after building)" if after else ""
        reused = f", {self.reused} from the study" if study else ""
        return f"{self.considered} layouts: {self.scored} scored now, {self.infeasible} infeasible{built}{reused}"


def _evaluate(
    plane: MLAPlane, design: Design, blocks: tuple[Block, ...], score: Score
) -> tuple[Design | None, float | None, str, tuple[str, ...]]:
    """Build and score one layout: ``(design, score, reason, warnings)``."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            candidate = plane.design_with(design, blocks)
        except ValueError as error:  # DesignError, or pydantic's ValidationError wrapping one
            return None, None, f"design refused: {error}", ()
        try:
            value = float(score(candidate))
        except ValueError as error:
            return candidate, None, f"score failed: {error}", ()
    notes = tuple(str(w.message) for w in caught)
    if not math.isfinite(value):
        return candidate, None, f"score is not finite ({value})", notes
    return candidate, value, "", notes


def _propose(
    plane: MLAPlane,
    new: tuple[Block, ...],
    current: tuple[Block, ...],
    last: tuple[Block, ...],
    symmetry: str,
) -> tuple[str, tuple[Block, ...], str]:
    """Lines 8-12: ``(base, layout, reason)`` of merging ``new`` (a block's orbit); ``reason`` '' if feasible."""
    outside = next((reason for reason in map(plane.outside_reason, new) if reason), "")
    if outside:
        return "current", (), outside
    blocks, reason = merge(current, new)
    if reason.startswith("conflict") and symmetry == "none":
        blocks, reason = merge(last, new)
        return "last", blocks, reason
    return "current", blocks, reason


def _sizes(sizes: Iterable[int] | None, cells: int) -> list[int]:
    chosen = list(range(1, cells)) if sizes is None else list(sizes)
    for d in chosen:
        if isinstance(d, bool) or not isinstance(d, int) or not 1 <= d <= cells:
            raise ValueError(
                f"sizes must be whole numbers of cells from 1 to {cells}; got {d!r}. Fix: e.g. range(1, {cells})."
            )
    return chosen


def algorithm2(
    design: Design,
    score: Score,
    *,
    plane: MLAPlane | None = None,
    min_lenslet_um: float | None = None,
    sizes: Iterable[int] | None = None,
    symmetry: str = "none",
    direction: str = "maximize",
    progress: ProgressCallback | None = None,
    cancel: CancelToken = None,
    record: Callable[[LayoutTrial], None] | None = None,
    lookup: Lookup | None = None,
) -> Algorithm2Result:
    """Run Algorithm 2 on the cell grid ``plane`` of ``design`` (see the module docstring).

    Parameters
    ----------
    design : Design
        The design whose MLA is searched (all else is kept).
    score : callable ``Design -> float``
        Candidate quality; higher is better for ``direction="maximize"``.
    plane : MLAPlane, optional
        The cell grid; or give ``min_lenslet_um`` for ``MLAPlane.from_design(design, min_lenslet_um)``.
    min_lenslet_um : float, optional
        Minimum lenslet size ``d_min`` in micrometres (when ``plane`` is not given).
    sizes : iterable of int, optional
        Aperture sizes to try, in cells, in this order (default ``range(1, M)``).
    symmetry : one of :data:`~.mla_cells.SYMMETRIES`
        Every merge is applied to the block's whole orbit.
    direction : "maximize" or "minimize"
    progress, cancel
        ``progress(done, total, message)`` per position; ``cancel`` is checked between
        candidates and raises :class:`~lfm_studio.engine.progress.CancelledError`.
    record : callable, optional
        Receives every :class:`LayoutTrial` considered, feasible or not, in order.
    lookup : callable, optional
        ``lookup(layout) -> (score, reason) | None``: a layout it knows is not built nor
        scored again (resuming a stored study; the search is deterministic, so it follows
        the same path).

    Returns
    -------
    Algorithm2Result
    """
    if (plane is None) == (min_lenslet_um is None):
        raise ValueError(
            f"give exactly one of plane and min_lenslet_um; got plane={plane!r}, min_lenslet_um={min_lenslet_um!r}. "
            "Fix: e.g. min_lenslet_um=2000."
        )
    if plane is None:
        plane = MLAPlane.from_design(design, float(min_lenslet_um))  # type: ignore[arg-type]
    check_symmetry(symmetry)
    if direction not in ("maximize", "minimize"):
        raise ValueError(f"direction must be 'maximize' or 'minimize'; got {direction!r}.")
    sign = 1.0 if direction == "maximize" else -1.0
    m = plane.cells
    order = _sizes(sizes, m)
    total = sum((m - d + 1) ** 2 for d in order)
    seen: set[tuple[Block, ...]] = set()
    counters = {"index": 0, "evaluated": 0, "infeasible": 0, "reused": 0, "scored": 0}

    def consider(blocks: tuple[Block, ...], params: dict, reason: str, best: float) -> float | None:
        """Score ``blocks`` (unless refused or already seen) and report it; the score or None."""
        start = time.perf_counter()
        candidate: Design | None = None
        value: float | None = None
        notes: tuple[str, ...] = ()
        stored = None
        if not reason:
            seen.add(blocks)
            stored = None if lookup is None else lookup(blocks)
            if stored is not None:
                value, reason = stored
                counters["reused"] += 1
            else:
                candidate, value, reason, notes = _evaluate(plane, design, blocks, score)
                counters["evaluated"] += 1
        if stored is None:
            counters["infeasible" if reason else "scored"] += 1
        accepted = value is not None and sign * value > best
        if record is not None:
            record(
                LayoutTrial(
                    counters["index"], params, blocks, value, candidate, reason, accepted,
                    time.perf_counter() - start, notes, stored is not None,
                )
            )  # fmt: skip
        counters["index"] += 1
        return value

    current = plane.initial_blocks()
    if not current:
        raise DesignError(
            f"no minimum lenslet of {plane.cell_um:.6g} um fits inside the {plane.pupil_diameter_um:.6g} um pupil. "
            "Fix: a smaller min_lenslet_um."
        )
    last = current
    value = consider(current, {"size": 1, "i": None, "j": None, "base": "initial"}, "", -math.inf)
    best = -math.inf if value is None else sign * value
    best_blocks = current
    history = [] if value is None else [value]
    done = 0
    for d in order:
        for i in range(m - d + 1):
            for j in range(m - d + 1):
                checkpoint(cancel, progress, done, total, f"Algorithm 2: size {d}, position ({i}, {j})")
                done += 1
                new = orbit(Block(i, j, d), m, symmetry)
                base, blocks, reason = _propose(plane, new, current, last, symmetry)
                if not reason and (blocks in seen or blocks == current):
                    continue  # no change, or a layout already scored
                params = {"size": d, "i": i, "j": j, "base": base}
                value = consider(blocks, params, reason, best)
                if value is not None and sign * value > best:
                    last, current, best, best_blocks = current, blocks, sign * value, blocks
                    history.append(value)
    checkpoint(cancel, progress, total, total, "Algorithm 2: done")
    best_design = None
    if math.isfinite(best):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            best_design = plane.design_with(design, best_blocks)
    return Algorithm2Result(
        best_blocks,
        best_design,
        sign * best,
        counters["evaluated"],
        counters["infeasible"],
        tuple(history),
        counters["reused"],
        counters["scored"],
    )
