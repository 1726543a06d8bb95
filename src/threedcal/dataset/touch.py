"""The gel's first-touch height: from contact radii against commanded depth, or from a
first-contact search (one frame per small step down at a few places)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage, optimize, stats
from tqdm import tqdm

from threedcal.collect.plan import TOUCH_BISECTION_MIN_PRESSES
from threedcal.dataset.contacts import SATURATED_DN, find_contact
from threedcal.errors import RegistrationError


@dataclass(frozen=True)
class TouchEstimate:
    """First-touch offset δ (true depth = commanded + δ) and the rim's edge offset e (None: not fitted)."""

    offset_mm: float
    edge_mm: float | None


# Commanded depths must span this much before a constant edge offset can be told from δ.
MIN_DEPTH_SPREAD_MM = 0.2


def estimate_touch(
    commanded_depth_mm: np.ndarray, contact_radius_mm: np.ndarray, sphere_radius_mm: float
) -> TouchEstimate:
    """δ with true depth = commanded + δ, from contact radii a: d_true = R − sqrt(R² − a²).

    A positive δ means the gel surface sits higher than the plan assumed (the probe touches earlier).
    At one depth the median over all contacts is used (robust to the few whose radius a halo or a
    clipped edge biased). The located rim, though, sits a near-constant distance e outside the true
    edge (blur, the gel's skirt), which that median takes for extra depth: by e / (da/dd), growing
    with depth as the contact's edge steepens. Probed at depths that span `MIN_DEPTH_SPREAD_MM` or
    more, a = sqrt(2R(d + δ) − (d + δ)²) + e is fitted for δ and e together (robust loss).
    """
    depth = np.asarray(commanded_depth_mm, dtype=float)
    a = np.asarray(contact_radius_mm, dtype=float)
    R = float(sphere_radius_mm)
    ok = np.isfinite(depth) & np.isfinite(a) & (a > 0) & (a < R)
    if not ok.any():
        raise RegistrationError("no contact with a usable radius to estimate the touch height")
    depth, a = depth[ok], a[ok]
    median = float(np.median(R - np.sqrt(R**2 - a**2) - depth))
    if np.ptp(depth) < MIN_DEPTH_SPREAD_MM:
        return TouchEstimate(median, None)

    def residual(params: np.ndarray) -> np.ndarray:
        d = np.clip(depth + params[0], 0.0, R)
        return np.sqrt(2 * R * d - d**2) + params[1] - a

    low = -float(depth.min()) + 1e-6  # every contact stays a contact
    start = np.array([max(median, low + 1e-6), 0.0])
    fit = optimize.least_squares(
        residual, start, bounds=([low, -R / 2], [R, R / 2]), loss="soft_l1", f_scale=0.02
    )
    return TouchEstimate(float(fit.x[0]), float(fit.x[1]))


# Pixels at or beyond these levels in a blank or a frame carry no shading change: left out.
DARK_DN = 3


@dataclass(frozen=True)
class ChangeDetector:
    """Where a frame differs from the blank beyond its noise, measured on the blank frames themselves.

    A frame's change is frame − g · blank per channel (g: the frame's exposure gain, a median ratio,
    so an LED or exposure flicker is not taken for contact), smoothed over `smooth_px`, saturated or
    black pixels left out. Its noise `sigma` (per channel) is measured by the same recipe on each
    blank frame against the mean of the others. A pixel is significant where the sum over channels
    of (change / sigma)² exceeds `threshold`: the larger of the χ²(3) level of `false_alarm` per
    pixel and twice the largest value any blank frame reached, so correlated noise or a flickering
    hot spot raises the bar instead of reading as contact.
    """

    blank: np.ndarray  # (H, W, 3) float32, the mean of the blank frames
    usable: np.ndarray  # (H, W, 3) bool: neither saturated nor black in any blank frame
    sigma: np.ndarray  # (3,) noise of one frame's smoothed change
    threshold: float
    smooth_px: float

    @classmethod
    def from_blanks(
        cls, blank_frames: np.ndarray, smooth_px: float = 1.5, false_alarm: float = 1e-6
    ) -> ChangeDetector:
        frames = np.asarray(blank_frames, dtype=np.float32)
        if frames.ndim != 4 or frames.shape[-1] != 3 or len(frames) < 3:
            raise RegistrationError(
                f"the touch search needs >= 3 RGB blank frames (N, H, W, 3) to measure the "
                f"noise, got {frames.shape} (the sensor profile's probing.n_blank)"
            )
        usable = ~((frames >= SATURATED_DN) | (frames <= DARK_DN)).any(axis=0)
        total = frames.sum(axis=0)
        changes = [
            _smoothed_change(f, (total - f) / (len(frames) - 1), usable, smooth_px) for f in frames
        ]
        sigma = np.median(
            [
                [1.4826 * float(np.median(np.abs(c[..., k][usable[..., k]]))) for k in range(3)]
                for c in changes
            ],
            axis=0,
        )
        sigma = np.maximum(sigma, 1e-3)
        # One blank frame against the mean of the others has (1 + 1/(n − 1)) / (1 + 1/n) the
        # variance of a frame against the mean of all: the levels below are conservative.
        blank_peak = max(float((((c / sigma) ** 2).sum(axis=-1)).max()) for c in changes)
        threshold = max(float(stats.chi2.isf(false_alarm, 3)), 2.0 * blank_peak)
        return cls(frames.mean(axis=0), usable, sigma, threshold, float(smooth_px))

    def significance(self, frame: np.ndarray, window=None) -> np.ndarray:
        """Sum over channels of (smoothed change / noise)²: ~χ²(3) where nothing changed.

        (H, W), or the (y0, y1, x0, x1) `window` of it (the exposure gain is still the frame's)."""
        frame = np.asarray(frame, dtype=np.float32)
        if frame.shape != self.blank.shape:
            raise RegistrationError(
                f"frame shape {frame.shape} differs from blank shape {self.blank.shape}"
            )
        usable = self.usable & (frame < SATURATED_DN) & (frame > DARK_DN)
        change = _smoothed_change(frame, self.blank, usable, self.smooth_px, window)
        return ((change / self.sigma) ** 2).sum(axis=-1)


def _smoothed_change(frame, reference, usable, smooth_px: float, window=None) -> np.ndarray:
    """frame − (g · reference + o) per channel over usable pixels, normalised-Gaussian smoothed:
    (H, W, 3), or (h, w, 3) over `window` (y0, y1, x0, x1). Gain g and offset o (an exposure or
    LED flicker is no contact) are medians over the whole frame, every other pixel each way."""
    height, width, channels = frame.shape
    y0, y1, x0, x1 = window or (0, height, 0, width)
    pad = int(np.ceil(4 * smooth_px))
    py0, py1, px0, px1 = (
        max(y0 - pad, 0),
        min(y1 + pad, height),
        max(x0 - pad, 0),
        min(x1 + pad, width),
    )
    out = np.zeros((y1 - y0, x1 - x0, channels), dtype=np.float32)
    for k in range(channels):
        ok = usable[..., k]
        sample = ok[::2, ::2]
        if not sample.any():
            continue
        f, ref = frame[::2, ::2, k][sample], reference[::2, ::2, k][sample]
        gain = float(np.median(f)) / max(float(np.median(ref)), 1e-6)
        offset = float(np.median(f - gain * ref))
        ok = ok[py0:py1, px0:px1]
        change = frame[py0:py1, px0:px1, k] - gain * reference[py0:py1, px0:px1, k] - offset
        change = np.where(ok, change, 0.0).astype(np.float32)
        weight = ndimage.gaussian_filter(ok.astype(np.float32), smooth_px)
        smooth = ndimage.gaussian_filter(change, smooth_px)
        smooth = np.where(weight > 0.5, smooth / np.maximum(weight, 1e-6), 0.0)
        out[..., k] = smooth[y0 - py0 : y1 - py0, x0 - px0 : x1 - px0]
    return out


@dataclass(frozen=True)
class TouchSearch:
    """The first-contact search's answer: δ with true depth = commanded + δ, and how it was found."""

    offset_mm: float  # the median over places
    place_offsets_mm: np.ndarray  # δ of each place
    onset_depth_mm: np.ndarray  # per place: the commanded depth of the first step with contact
    steps_fitted: np.ndarray  # per place: steps in the fit
    signal: np.ndarray  # per step: the contact signal the fit saw (0 without contact)
    exponent: float  # p of signal ∝ (c + δ)^p, measured from the steps (or as given)


# The smoothing (px) of the changes the contact signal is taken from.
TOUCH_SMOOTHING_PX = 1.0
# The window the signal is summed over: this many probe radii about the place, clipped to the frame.
TOUCH_WINDOW_RADII = 3.0
# A step has contact where its signal exceeds this many times the blanks' own (and twice their largest).
TOUCH_SIGNAL_SIGMAS = 6.0
# The depth past the onset the signal is fitted over: 8 steps of 0.02 mm. Chosen on the bench's
# elastic DIGIT (sharp and 6 px blurred cameras) and geometric DIGIT, seeds 11-14 (docs/explanation/registration.md).
TOUCH_FIT_SPAN_MM = 0.16
# The exponents p of signal ∝ (c + δ)^p the search chooses from.
TOUCH_EXPONENTS = np.round(np.arange(1.0, 3.0001, 0.05), 2)


def measure_touch_search(
    frames,
    blank_frames: np.ndarray,
    depth_mm: np.ndarray,
    place: np.ndarray,
    centres_px: np.ndarray,
    px_per_mm: float,
    reach_mm: float,
    span_mm: float,
    progress: bool = False,
) -> TouchSearch:
    """δ from the frames of a first-contact search: one frame per step (`frames[i]` at commanded
    depth `depth_mm[i]`, below the nominal touch and corrected for the gel's sag there, at place
    `place[i]`, its contact expected at `centres_px[i]` from the registration).

    Each step's change (frame − blank, `ChangeDetector`'s recipe, over `TOUCH_WINDOW_RADII` probe
    radii `reach_mm` about the place) is projected onto its place's template, the mean change of
    its three deepest steps: the contact signal L. A projection is linear in the image, so the
    camera's blur and the smoothing scale it but add nothing to it — unlike a contact's size, which
    a blur widens by a constant that a line through the sizes takes for depth (behind a 6 px
    blur, 0.36 mm). The same projection of each blank frame against the others' mean gives L's noise; a
    step has contact where L exceeds `TOUCH_SIGNAL_SIGMAS` times it and twice the largest blank's.
    `fit_touch_onset` then finds where L grows from.
    """
    detector = ChangeDetector.from_blanks(blank_frames, smooth_px=TOUCH_SMOOTHING_PX)
    blanks = np.asarray(blank_frames, dtype=np.float32)
    total = blanks.sum(axis=0)
    height, width = detector.blank.shape[:2]
    reach_px = TOUCH_WINDOW_RADII * reach_mm * px_per_mm
    depth = np.asarray(depth_mm, dtype=float)
    place = np.asarray(place)
    signal = np.zeros(len(depth))
    touching = np.zeros(len(depth), bool)
    bar = tqdm(total=len(depth), desc="touch search", unit="frame", disable=not progress)
    for p in np.unique(place):
        rows = np.flatnonzero(place == p)
        rows = rows[np.argsort(depth[rows], kind="stable")]
        cx, cy = np.median(np.asarray(centres_px, dtype=float)[rows], axis=0)
        window = (
            max(int(cy - reach_px), 0),
            min(int(cy + reach_px) + 1, height),
            max(int(cx - reach_px), 0),
            min(int(cx + reach_px) + 1, width),
        )
        if window[1] - window[0] < 3 or window[3] - window[2] < 3:
            raise RegistrationError(f"touch search place {p}: its contact lies off the frame")

        def change(frame, reference, usable, window=window):
            return _smoothed_change(frame, reference, usable, TOUCH_SMOOTHING_PX, window) / (
                detector.sigma
            )

        changes = []
        for i in rows:
            frame = np.asarray(frames[i], dtype=np.float32)
            usable = detector.usable & (frame < SATURATED_DN) & (frame > DARK_DN)
            changes.append(change(frame, detector.blank, usable))
            bar.update()
        template = np.mean(changes[-3:], axis=0)
        norm = float((template * template).sum())
        if not norm > 0:
            raise RegistrationError(f"touch search place {p}: no change at its deepest steps")
        quiet = [
            float((change(f, (total - f) / (len(blanks) - 1), detector.usable) * template).sum())
            / norm
            for f in blanks
        ]
        level = max(TOUCH_SIGNAL_SIGMAS * float(np.std(quiet, ddof=1)), 2 * max(map(abs, quiet)))
        signal[rows] = [float((c * template).sum()) / norm for c in changes]
        touching[rows] = signal[rows] > level
    bar.close()
    return fit_touch_onset(depth, place, np.where(touching, signal, 0.0), touching, span_mm)


def _onset_steps(c: np.ndarray, on: np.ndarray, span_mm: float, p) -> np.ndarray:
    """Indices of a place's steps (sorted by depth) the line is fitted to, or an error naming why not.
    Contact counts from the step after the last one without it: a lone false alarm above that is
    passed over."""
    if on.all():
        raise RegistrationError(
            f"touch search place {p}: contact already at the first step ({c[0]:+.3f} mm): "
            "the gel sits higher than the search starts — raise the sensor profile's "
            "probing.touch_uncertainty_mm — or the image drifted from the blank frames"
        )
    if not on[-1]:
        raise RegistrationError(
            f"touch search place {p}: no contact even at the last step ({c[-1]:+.3f} mm): "
            "the gel sits lower than the search reaches — raise probing.touch_uncertainty_mm "
            "or plan.touch_search.beyond_mm"
        )
    onset = int(np.flatnonzero(~on)[-1]) + 1  # contact from here on
    fit = np.flatnonzero((np.arange(len(c)) >= onset) & (c <= c[onset] + span_mm + 1e-9))
    if len(fit) < 3:
        raise RegistrationError(
            f"touch search place {p}: {len(fit)} steps with contact within {span_mm:g} mm "
            "of its onset; at least 3 are needed (a smaller step_mm or a larger beyond_mm)"
        )
    return fit


def fit_touch_onset(
    depth_mm: np.ndarray,
    place: np.ndarray,
    signal: np.ndarray,
    touching: np.ndarray,
    span_mm: float,
    exponent: float | None = None,
) -> TouchSearch:
    """δ from a contact signal L against commanded depth c at each place of a first-contact search.

    Contact begins where c + δ = 0, and near it L grows as a power of the true depth:
    L = α (c + δ)^p, α free per place (the LEDs, the place). p depends on the gel's mechanics (about
    2 for a rigid cap, whose volume grows as d²; about 1.5 for an elastic gel, whose surface also
    sinks around the contact, as a·d/r), so unless `exponent` gives it, p is the one of
    `TOUCH_EXPONENTS` whose lines through L^(1/p) fit L best, all places together. From the first
    step after which every step shows contact (`touching`), the steps within `span_mm` are fitted
    by least squares and δ is the line's zero; the median over places is returned. Contact at every
    step of a place, none at its last, or fewer than 3 steps to fit are errors that say which
    setting to change.
    """
    depth = np.asarray(depth_mm, dtype=float)
    signal = np.asarray(signal, dtype=float)
    touching = np.asarray(touching, dtype=bool)
    place = np.asarray(place)
    groups = []
    for p in np.unique(place):
        rows = np.flatnonzero(place == p)
        rows = rows[np.argsort(depth[rows], kind="stable")]
        fit = _onset_steps(depth[rows], touching[rows], span_mm, p)
        groups.append((p, rows[fit]))

    def lines(p_exp: float):
        out, sse = [], 0.0
        for _, rows in groups:
            c, y = depth[rows], np.clip(signal[rows], 0.0, None)
            slope, intercept = np.polyfit(c, y ** (1.0 / p_exp), 1)
            sse += float(np.sum((np.clip(slope * c + intercept, 0.0, None) ** p_exp - y) ** 2))
            out.append((slope, intercept))
        return out, sse

    if exponent is None:
        exponent = float(min(TOUCH_EXPONENTS, key=lambda e: lines(float(e))[1]))
    offsets, onsets, used = [], [], []
    for (p, rows), (slope, intercept) in zip(groups, lines(exponent)[0], strict=True):
        if not slope > 0:
            raise RegistrationError(
                f"touch search place {p}: the contact does not grow with depth (slope {slope:.3g})"
            )
        offsets.append(intercept / slope)
        onsets.append(depth[rows[0]])
        used.append(len(rows))
    offsets = np.asarray(offsets)
    return TouchSearch(
        offset_mm=float(np.median(offsets)),
        place_offsets_mm=offsets,
        onset_depth_mm=np.asarray(onsets),
        steps_fitted=np.asarray(used),
        signal=signal,
        exponent=float(exponent),
    )


@dataclass(frozen=True)
class TouchPress:
    """One press of a first-contact search: its commanded depth and what the frame showed."""

    depth_mm: float
    signal: float  # the contact signal L (0 without contact is not implied: see `contact`)
    contact: bool


class TouchBisection:
    """The first-contact search at one place, decided press by press: `next_depth()`, press there,
    `observe(frame)`, until `next_depth()` is None; then `result()`.

    `presses` presses in all, commanded depths (below the nominal touch) within [low_mm, high_mm]:
    1. high_mm, the deepest: it must touch; its change from the blank is the template onto which
       every later frame is projected (the contact signal L of `measure_touch_search`), and its
       contact's centre is where the window is cut;
    2. `bisections` halvings of [low_mm, high_mm] on whether L exceeds its noise level (`bisect`):
       the onset to within (high − low) / 2^bisections;
    3. the rest past the bracket's contact end, spread over `span_mm`, so that the growth
       L = α (c + δ)^p can be fitted from the onset (`fit_touch_onset`, L less the mean L of the
       presses without contact: the frames' drift since the blanks) and δ read where it starts;
       the first of them at low_mm itself when every halving touched (the onset in the lowest
       halving's cell, or the gel above the window).

    A contact at every press (the gel higher than low_mm) or none at high_mm (lower than it) is a
    RegistrationError naming the setting to change, as the stepped search's are."""

    def __init__(
        self,
        blank_frames: np.ndarray,
        low_mm: float,
        high_mm: float,
        presses: int,
        px_per_mm: float,
        reach_mm: float,
        span_mm: float = TOUCH_FIT_SPAN_MM,
        bisections: int | None = None,
    ):
        if presses < TOUCH_BISECTION_MIN_PRESSES:
            raise RegistrationError(
                f"a bisecting touch search needs >= {TOUCH_BISECTION_MIN_PRESSES} presses "
                f"(the deepest, one halving, {TOUCH_BISECTION_MIN_PRESSES - 2} to fit), got {presses}"
            )
        if not (math.isfinite(low_mm) and math.isfinite(high_mm) and low_mm < high_mm):
            raise RegistrationError(
                f"touch search depths must rise from low to high, got {low_mm}, {high_mm}"
            )
        self.detector = ChangeDetector.from_blanks(blank_frames, smooth_px=TOUCH_SMOOTHING_PX)
        self._blanks = np.asarray(blank_frames, dtype=np.float32)
        self.low, self.high = float(low_mm), float(high_mm)
        self.presses = int(presses)
        fit = max(2, self.presses // 2 - 1)
        self.bisections = int(bisections) if bisections is not None else self.presses - 1 - fit
        self.span_mm = float(span_mm)
        self.place_px: tuple[float, float] | None = None  # found at the deepest press
        self.reach_px = TOUCH_WINDOW_RADII * float(reach_mm) * float(px_per_mm)
        self.pressed: list[TouchPress] = []
        self._template: np.ndarray | None = None
        self._window = None
        self.level = math.nan
        self.bracket = (self.low, self.high)  # [no contact, contact] after the halvings so far

    def next_depth(self) -> float | None:
        """Where to press next (mm below the nominal touch); None when the search is done."""
        k = len(self.pressed)
        if k >= self.presses:
            return None
        if k == 0:
            return self.high
        if k <= self.bisections:
            low, high = self.bracket
            return (low + high) / 2
        if not any(not p.contact for p in self.pressed) and self.low not in self._depths():
            return self.low  # every halving touched: is the gel above the window, or just in?
        rest = self.presses - 1 - self.bisections
        top = min(self.bracket[1] + self.span_mm, self.high)  # never past the deepest press
        step = (top - self.bracket[1]) / (rest + 1)
        past = sum(d != self.low for d in self._depths()[self.bisections + 1 :])
        return self.bracket[1] + step * (past + 1)

    def _depths(self) -> list[float]:
        return [p.depth_mm for p in self.pressed]

    def observe(self, depth_mm: float, frame: np.ndarray) -> TouchPress:
        """The frame (mean of the press's frames) pressed at `depth_mm`: its signal and verdict."""
        frame = np.asarray(frame, dtype=np.float32)
        if not self.pressed:
            self._first(frame)
        signal = self._signal(frame)
        press = TouchPress(float(depth_mm), signal, bool(signal > self.level))
        self.pressed.append(press)
        if 1 < len(self.pressed) <= self.bisections + 1:
            low, high = self.bracket
            self.bracket = (low, depth_mm) if press.contact else (depth_mm, high)
        return press

    def _first(self, frame: np.ndarray) -> None:
        """The deepest press: where its contact is, the window about it, the template, the level."""
        detector = self.detector
        contact = find_contact(frame, detector.blank)
        if contact is None:
            raise RegistrationError(
                f"touch search: no contact even at the deepest press ({self.high:+.3f} mm): the "
                "gel sits lower than the search reaches — raise probing.touch_uncertainty_mm or "
                "plan.touch_search.beyond_mm"
            )
        self.place_px = (contact.x_px, contact.y_px)
        height, width = detector.blank.shape[:2]
        cx, cy, reach = *self.place_px, self.reach_px
        self._window = (
            max(int(cy - reach), 0),
            min(int(cy + reach) + 1, height),
            max(int(cx - reach), 0),
            min(int(cx + reach) + 1, width),
        )
        self._template = self._change(frame, detector.blank, self._usable(frame))
        norm = float((self._template * self._template).sum())
        if not norm > 0:
            raise RegistrationError("touch search: no change at the deepest press")
        self._norm = norm
        total = self._blanks.sum(axis=0)
        quiet = [
            self._project(self._change(f, (total - f) / (len(self._blanks) - 1), detector.usable))
            for f in self._blanks
        ]
        self.level = max(
            TOUCH_SIGNAL_SIGMAS * float(np.std(quiet, ddof=1)), 2 * max(map(abs, quiet))
        )

    def _usable(self, frame: np.ndarray) -> np.ndarray:
        return self.detector.usable & (frame < SATURATED_DN) & (frame > DARK_DN)

    def _change(self, frame, reference, usable) -> np.ndarray:
        change = _smoothed_change(frame, reference, usable, TOUCH_SMOOTHING_PX, self._window)
        return change / self.detector.sigma

    def _project(self, change: np.ndarray) -> float:
        return float((change * self._template).sum()) / self._norm

    def _signal(self, frame: np.ndarray) -> float:
        return self._project(self._change(frame, self.detector.blank, self._usable(frame)))

    def result(self) -> TouchSearch:
        """δ (true depth = commanded + δ) from the presses: the growth fitted from the onset."""
        return bisection_result([self])

    def fit_input(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(depth, signal, touching) of every press, the signal less the mean of the presses
        without contact (the frames' drift since the blanks); checked complete and bracketed."""
        if len(self.pressed) < self.presses:
            raise RegistrationError(
                f"touch search: {len(self.pressed)} of its {self.presses} presses were made"
            )
        depth = np.array([p.depth_mm for p in self.pressed])
        touching = np.array([p.contact for p in self.pressed])
        signal = np.array([p.signal for p in self.pressed])
        if touching.all():
            raise RegistrationError(
                f"touch search: contact at every press, down to {depth.min():+.3f} mm: the gel "
                "sits higher than the search starts — raise probing.touch_uncertainty_mm — or "
                "the image drifted from the blank frames"
            )
        baseline = float(signal[~touching].mean())
        return depth, np.where(touching, signal - baseline, 0.0), touching


def bisection_result(searches, span_mm: float = TOUCH_FIT_SPAN_MM) -> TouchSearch:
    """δ from the places' bisecting searches (`TouchBisection`, every press made): their presses
    fitted together by `fit_touch_onset` (one exponent p, δ the median over places)."""
    parts = [search.fit_input() for search in searches]
    place = np.concatenate([np.full(len(d), k) for k, (d, _, _) in enumerate(parts)])
    depth, signal, touching = (np.concatenate([p[i] for p in parts]) for i in range(3))
    return fit_touch_onset(depth, place, signal, touching, span_mm)


class PlanTouchSearch:
    """A plan's bisecting touch search: its touch rows, each place's presses asked of its own
    `TouchBisection` as the collection reaches them (`depth`, `observe`). `begin(blank_frames)`
    once the blanks are taken.

    `place` (per touch row, in plan order) groups the rows; `sag_mm` (per row) is added to the
    search's depth below the nominal touch to give the depth commanded (a domed gel's sag at the
    place, as the plan compensates it) and taken off what is observed."""

    def __init__(
        self,
        place,
        low_mm: float,
        high_mm: float,
        px_per_mm: float,
        reach_mm: float,
        sag_mm=None,
    ):
        self.place = np.asarray(place, dtype=int)
        self.sag = np.zeros(len(self.place)) if sag_mm is None else np.asarray(sag_mm, float)
        self.low, self.high = float(low_mm), float(high_mm)
        self.px_per_mm, self.reach_mm = float(px_per_mm), float(reach_mm)
        self.searches: dict[int, TouchBisection] = {}

    def begin(self, blank_frames: np.ndarray) -> None:
        counts = {int(p): int((self.place == p).sum()) for p in np.unique(self.place)}
        self.searches = {
            p: TouchBisection(blank_frames, self.low, self.high, n, self.px_per_mm, self.reach_mm)
            for p, n in counts.items()
        }

    def depth(self, k: int) -> float:
        """The commanded depth of touch row `k` (its place's next press)."""
        depth = self.searches[int(self.place[k])].next_depth()
        if depth is None:
            raise RegistrationError(f"touch row {k}: its place has made all its presses")
        return depth + float(self.sag[k])

    def observe(self, k: int, depth_mm: float, frames: np.ndarray) -> TouchPress:
        """Touch row `k`'s frames (their mean is judged), pressed at commanded `depth_mm`."""
        frame = np.asarray(frames, dtype=np.float32).mean(axis=0)
        return self.searches[int(self.place[k])].observe(depth_mm - float(self.sag[k]), frame)

    def result(self) -> TouchSearch:
        return bisection_result(list(self.searches.values()))


def planned_touch_search(
    xy_mm: np.ndarray,
    planned_depth_mm: np.ndarray,
    low_mm: float,
    high_mm: float,
    px_per_mm: float,
    reach_mm: float,
) -> PlanTouchSearch:
    """The bisecting search of a plan's touch rows (plan x, y and depth per row, in plan order):
    a place per distinct (x, y); each row's planned depth is the deepest its press may take, the
    search's `high_mm` plus the dome's sag there, which the search adds to every press."""
    xy = np.asarray(xy_mm, dtype=float).reshape(-1, 2)
    _, place = np.unique(xy, axis=0, return_inverse=True)
    sag = np.asarray(planned_depth_mm, dtype=float) - float(high_mm)
    return PlanTouchSearch(place.ravel(), low_mm, high_mm, px_per_mm, reach_mm, sag_mm=sag)
