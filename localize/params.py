"""Parameters of the particle filter (frozen; derive variants with :func:`dataclasses.replace`).

Symbols follow the papers (``../shared/papers/NOTES.md``): ``delta`` the half-width of the
initial square (001 Algorithm 1), ``(a, b)`` the step-length genomes of eq. 13, ``W, K, T`` the
window, award and threshold of the mass-centered update (000 eq. 5, 001 eqs. 8-10).

Defaults come from the cross-validated search of ``benchmarks/localize_tune.py`` (5-fold by
walk, parameters chosen leave-one-floor-out) on the ILC traces and a simulated site, not from
the papers: the threshold ``T = 0.5 uT`` (the papers' 0.05 uT over-trusts maps built from
surveys, whose step-scale changes barely repeat across walks), strength only (azimuth and polar
on UFH steps gave nothing: the phone's rotation vector takes north from the local field, so the
measured azimuth hardly varies), radio weight updates and re-injection around far fixes, and
3000 particles until the filter converges. ``paper_params()`` gives the papers' values.
"""

from __future__ import annotations

import json
import math
import numbers
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields, replace

import numpy as np

from localize.errors import LocalizationError
from survey.errors import require_type

__all__ = ["MAX_STEP_M", "WEIGHT_MODES", "FeatureParams", "FilterParams"]

#: Most particles a filter may have (``indoormap localize --particles`` allows as many): a
#: million particles of one user take about 100 MB.
MAX_PARTICLES = 1_000_000
#: Field features with their own FeatureParams.
FEATURE_NAMES = ("strength", "azimuth", "polar", "deviation")
#: Magnetic weight updates the filter knows.
WEIGHT_MODES = ("mass_centered", "gaussian", "dtw", "none")
#: Longest step a walker takes (m): longer modelled steps come from sensor glitches (one
#: accelerometer value of 1e30) and are cut to it, by the filter and the alignment.
MAX_STEP_M = 1.5
#: FilterParams numbers that may be infinite (a spread or distance never reached).
UNBOUNDED_OK = frozenset({"mode_spread_m", "radio_inject_distance_m", "guide_inject_distance_m",
                          "shrink_spread_m", "recovery_max_half_width_m"})
#: FilterParams numbers that are noise, drifts or distances: none may be negative (a negative
#: standard deviation was taken as its absolute value, or crashed deep in the filter).
NOT_NEGATIVE = ("n_particles_start", "shrink_spread_m", "shrink_after_steps",
                "init_from_fix_scale", "weinberg_nominal", "step_length_nominal_m",
                "genome_a_sd", "genome_b_sd", "genome_drift_a", "genome_drift_b",
                "step_length_noise_m", "heading_noise_deg", "heading_bias_sd_deg",
                "heading_bias_drift_deg", "gaussian_window", "neff_fraction",
                "radio_inject_distance_m", "guide_inject_distance_m", "mode_spread_m",
                "recovery_max_half_width_m")


def is_number(v: object) -> bool:
    """A real number (numpy's too), not a bool."""
    return isinstance(v, numbers.Real) and not isinstance(v, bool)


def is_switch(v: object) -> bool:
    """A value a switch takes: True or False (numpy's too), or the whole number 0 or 1 (an
    ``int()`` of a config value); not text (``"False"`` was taken as true)."""
    return isinstance(v, (bool, np.bool_)) or (isinstance(v, (int, np.integer))
                                               and v in (0, 1))


def _set_numbers(obj, unbounded: frozenset[str] = frozenset(), prefix: str = "") -> None:
    """Check and store the number fields of a frozen dataclass ``obj`` (those whose default
    is a number or a tuple of numbers) as Python numbers of their default's type, tuples as
    tuples (a list or array given for a range, numpy numbers: ``to_json`` writes them, and
    the parameters stay hashable); a LocalizationError for NaN, an infinity (unless the
    field is in ``unbounded``), a fraction where a count is expected, or no number."""
    for f in fields(obj):
        default = f.default if isinstance(f.default, tuple) else (f.default,)
        if not all(is_number(v) for v in default):
            continue
        value = getattr(obj, f.name)
        try:
            values = tuple(value) if isinstance(f.default, tuple) else (value,)
        except TypeError:
            values = ()
        ok = len(values) == len(default) and all(
            is_number(v) and not math.isnan(v) and (f.name in unbounded or not math.isinf(v))
            and (not isinstance(d, int) or float(v).is_integer())
            for v, d in zip(values, default))
        if not ok:
            what = ("a whole number" if isinstance(default[0], int) else "a finite number") \
                if len(default) == 1 else f"{len(default)} finite numbers"
            raise LocalizationError(f"{prefix}{f.name} must be {what}, got {value!r}")
        plain = tuple(type(d)(v) for v, d in zip(values, default))
        object.__setattr__(obj, f.name, plain if isinstance(f.default, tuple) else plain[0])


def _set_flags(obj, prefix: str = "") -> None:
    """Check and store the switches of a frozen dataclass ``obj`` (fields whose default is a
    bool) as Python bools: a LocalizationError for anything but True or False (numpy's, and
    the whole numbers 0 and 1, too). Text read from a file or the environment, ``"False"``,
    was taken as true."""
    for f in fields(obj):
        if isinstance(f.default, bool):
            value = getattr(obj, f.name)
            if not is_switch(value):
                raise LocalizationError(f"{prefix}{f.name} must be True or False, got "
                                        f"{value!r}")
            object.__setattr__(obj, f.name, bool(value))


@dataclass(frozen=True)
class FeatureParams:
    """Mass-centered update of one field feature (000 eq. 5; 001 eqs. 8-10).

    Attributes
    ----------
    enabled : bool
    window : int
        ``W``: steps in the sliding window of the mean delta error.
    award : float
        ``K``: the coefficient is ``K / max(err, T)``. With resampling every step the weights
        are normalised, so ``K`` only scales all weights alike (kept for fidelity).
    threshold : float
        ``T``: error (feature unit) below which the award stops growing.
    span : int
        Steps between the two values of a delta (1 = the paper's step-to-step delta; more
        compares changes over longer distances).
    smooth : int
        Moving average (steps) applied alike to the observed and the map series before taking
        deltas (1 = none).
    std_scale : float
        When > 0 the threshold grows with the map uncertainty at the particle:
        ``T_i = max(T, std_scale * std_i)`` (needs the layer's std raster).
    """

    enabled: bool = True
    window: int = 3
    award: float = 70.0
    threshold: float = 0.05
    span: int = 1
    smooth: int = 1
    std_scale: float = 0.0

    def __post_init__(self) -> None:
        _set_numbers(self, prefix="FeatureParams.")
        _set_flags(self, prefix="FeatureParams.")

    @property
    def history(self) -> int:
        """Values (steps) of history the feature needs."""
        return self.window + self.span + self.smooth - 1


@dataclass(frozen=True)
class FilterParams:
    """Everything the particle filter needs besides the map and the steps.

    Attributes
    ----------
    n_particles : int
        Particles per user (001: 3000 in the office tests, 300 in the cost figures).
    n_particles_start : int
        Particles while the filter has not converged (0 = ``n_particles``): a start from a
        radio fix several metres off needs many hypotheses (001 used 3000 in the office);
        once the spread falls below ``shrink_spread_m`` or after ``shrink_after_steps`` steps
        the set is resampled down to ``n_particles``. Single-user localizer only.
    shrink_spread_m : float
    shrink_after_steps : int
    init_half_width_m : float
        ``delta``: half-width of the square particles start in around a given position (m).
    init_from_fix_scale : float
        With a radio fix of accuracy ``sigma`` the half-width is ``max(init_half_width_m,
        init_from_fix_scale * sigma)``.
    step_model : {"frequency", "weinberg"}
        Input of the genome step-length model ``L = a F + b``: the step frequency (001 eq. 13,
        ``F = f`` in Hz) or Weinberg's acceleration swing (002, ``F = (a_max - a_min)^(1/4)``);
        on the ILC traces the walks' step lengths correlate with the latter (r = 0.64) and not
        with the frequency (r = -0.28).
    step_freq_nominal_hz : float
        Frequency assumed when a step has none (Hz); the nominal ``F`` of the frequency model.
    weinberg_nominal : float
        Nominal ``F`` of the Weinberg model ((m/s^2)^(1/4)).
    step_length_nominal_m : float
        Step length at the nominal frequency that the genome prior is centred on (m).
    genome_a_mean, genome_a_sd : float
        Prior of the slope ``a`` (m per Hz); ``b`` is set so that the prior mean length at the
        nominal frequency is ``step_length_nominal_m``.
    genome_b_sd : float
        Prior spread of ``b`` (m): the initial step-length uncertainty.
    genome_a_range, genome_b_range : (float, float)
        Bounds the genomes are kept in.
    step_length_range_m : (float, float)
        Bounds of a genome's step length at the nominal frequency (m): without them the
        population can evolve towards standing still, which in a wrong place matches small
        observed field changes better than walking does.
    genome_drift_a, genome_drift_b : float
        SD of the per-step genome drift ``delta_a``, ``delta_b`` (eq. 13).
    step_length_noise_m : float
        SD of ``Delta`` in eq. 13 (m).
    heading_noise_deg : float
        SD of ``Delta'`` in eq. 15 (deg).
    heading_bias_sd_deg, heading_bias_drift_deg : float
        Optional per-particle heading bias genome (deg): initial spread and per-step drift; it
        absorbs slowly varying compass errors the heading-offset map does not know (0 = off).
    turn_correction : bool
        Shorten turning steps by ``sin((pi - theta) / 2)`` (eq. 14).
    use_heading_offset : bool
        Subtract the map's heading offset at each particle from the compass heading (eq. 15).
    weight_mode : str
        ``"mass_centered"`` (000/001), ``"gaussian"`` (002-style Gaussian likelihood),
        ``"dtw"`` (Magicol-style DTW over raw magnetometer samples) or ``"none"``.
    strength, azimuth, polar : FeatureParams
        Per-feature mass-centered parameters; azimuth and polar only count on UFH steps
        (001 eq. 12).
    deviation : FeatureParams
        An extension (off by default): the compass deviation, observed as compass heading
        minus gyroscope heading (the unknown constant between them cancels in the deltas) and
        mapped by the heading-offset layer; the direction anomaly of the field in a frame
        that, unlike the phone's rotation vector, does not follow the local field.
    gaussian_sigma : float
        SD of the Gaussian likelihood (uT).
    gaussian_window : int
        Steps of the strength profile compared (window mean removed, so a per-walk offset
        cancels).
    neff_fraction : float
        Resample when the effective sample size falls below this fraction of n (gaussian and
        dtw modes; the mass-centered mode resamples every step as in 001).
    dtw_sigma : float
        Scale of the DTW likelihood ``exp(-D / (m * dtw_sigma))`` (uT).
    radio_inject_fraction : float
        At every step with a radio fix, this share of the particles is re-drawn around the
        fix (square of half-width ``max(radio_sigma_floor_m, init_from_fix_scale * sigma)``):
        a filter locked onto a wrong corridor can find the way back (0 = off).
    radio_inject_distance_m : float
        Inject only when the fix is farther than this from the current estimate (m; 0 =
        at every fix).
    radio_inject_rule : {"distance", "fit"}
        When to inject: ``"distance"``, whenever the fix is ``radio_inject_distance_m`` or
        more from the estimate; ``"fit"`` (augmented MCL, Thrun et al., Probabilistic
        Robotics 8.3.5), when the particles' mean radio likelihood over the last few scans
        (``radio_fit_fast``) falls below its long-run average (``radio_fit_slow``), with the
        share ``min(radio_inject_fraction, 1 - fast / slow)``: a wrong fix that the filter's
        cloud has seen agree before does not pull particles away. Models without a
        likelihood use the distance rule.
    radio_fit_fast, radio_fit_slow : float
        Rates (per scan) of the two averages of the ``"fit"`` rule.
    radio_update : bool
        Multiply weights by the radio likelihood whenever a step carries a scan (the paper
        uses Wi-Fi/BLE only to start).
    radio_sigma_floor_m : float
        Smallest accuracy assumed for a radio fix (m).
    radio_outlier : float
        Mixture weight of a uniform outlier term in the radio update (keeps particles alive
        when the fix is wrong).
    radio_guide : {"fixes", "align"}
        What the radio update and the re-injection use. ``"fixes"`` (default): each scan's own
        fix (``radio_sigma_floor_m``, ``radio_inject_distance_m``, ``radio_inject_rule``).
        ``"align"``: the walk alignment's real-time position
        (:class:`~localize.align.WalkAligner` run beside the filter on the same steps and
        fixes: the step track fitted to all the walk's fixes so far and to the walls), at every
        step, as a Gaussian of ``max(its search's spread, guide_sigma_m)``
        (:attr:`~localize.align.WalkAligner.search_spread_m`), with the injection when it is
        ``guide_inject_distance_m`` or more from the estimate (``radio_sigma_floor_m``,
        ``radio_inject_distance_m`` and ``radio_inject_rule`` are then not used); it costs
        the alignment's time (about 6 ms per step). Better on the simulated site with built
        maps, neutral on the real traces, worse where the alignment is poor
        (docs/localize.md); ``--method auto`` uses it on floors whose magnetic map is good.
        After a given start position the fixes are used (the alignment would hold the start
        as a fix of 1 m, a wrong one for its whole window); :attr:`Localizer.guided` says
        which ran. Without a radio model neither is used.
    guide_sigma_m : float
        Smallest SD (m) of the Gaussian around the alignment's position.
    guide_inject_distance_m : float
        Inject around the alignment's position when it is this far or farther from the
        filter's estimate (m).
    mode_spread_m : float
        When the particles spread more than this (RMS, m) the estimate is the densest part of
        the cloud (:func:`~localize.particles.estimate_mode`) instead of the mean (001), which
        for a cloud split between two corridors lies in the wall between them (inf = always
        the mean).
    recovery_half_width_m : float
        Half-width of the square particles are re-drawn in when all died (m); doubles on each
        consecutive recovery up to ``recovery_max_half_width_m``.
    recovery_max_half_width_m : float
    """

    n_particles: int = 300
    n_particles_start: int = 3000
    shrink_spread_m: float = 2.0
    shrink_after_steps: int = 40
    init_half_width_m: float = 2.0
    init_from_fix_scale: float = 1.5
    step_model: str = "frequency"
    step_freq_nominal_hz: float = 1.8
    weinberg_nominal: float = 1.7
    step_length_nominal_m: float = 0.65
    genome_a_mean: float = 0.3
    genome_a_sd: float = 0.05
    genome_b_sd: float = 0.08
    genome_a_range: tuple[float, float] = (0.05, 1.0)
    genome_b_range: tuple[float, float] = (-0.8, 0.8)
    step_length_range_m: tuple[float, float] = (0.35, 1.0)
    genome_drift_a: float = 0.003
    genome_drift_b: float = 0.005
    step_length_noise_m: float = 0.05
    heading_noise_deg: float = 8.0
    heading_bias_sd_deg: float = 3.0
    heading_bias_drift_deg: float = 0.3
    turn_correction: bool = True
    use_heading_offset: bool = True
    weight_mode: str = "mass_centered"
    strength: FeatureParams = field(default_factory=lambda: FeatureParams(threshold=0.5))
    azimuth: FeatureParams = field(default_factory=lambda: FeatureParams(enabled=False,
                                                                         threshold=1.0))
    polar: FeatureParams = field(default_factory=lambda: FeatureParams(enabled=False,
                                                                       threshold=0.5))
    deviation: FeatureParams = field(default_factory=lambda: FeatureParams(enabled=False,
                                                                           threshold=0.5))
    gaussian_sigma: float = 1.1
    gaussian_window: int = 3
    neff_fraction: float = 0.5
    dtw_sigma: float = 1.0
    radio_inject_fraction: float = 0.1
    radio_inject_distance_m: float = 6.0
    radio_inject_rule: str = "distance"
    radio_fit_fast: float = 0.5
    radio_fit_slow: float = 0.05
    radio_update: bool = True
    radio_sigma_floor_m: float = 3.0
    radio_outlier: float = 0.1
    radio_guide: str = "fixes"
    guide_sigma_m: float = 5.0
    guide_inject_distance_m: float = 4.0
    mode_spread_m: float = float("inf")
    recovery_half_width_m: float = 4.0
    recovery_max_half_width_m: float = 30.0

    def __post_init__(self) -> None:
        _set_numbers(self, UNBOUNDED_OK)
        _set_flags(self)
        for f in fields(self):  # the features: a dict of fields over that feature's defaults
            value = getattr(self, f.name)
            if f.name in FEATURE_NAMES and not isinstance(value, FeatureParams):
                object.__setattr__(self, f.name, _feature(f.name, f.default_factory(), value))
        self.validate()

    @classmethod
    def coerce(cls, params: FilterParams | Mapping | None, what: str) -> FilterParams:
        """``params`` as FilterParams: None gives the defaults, a dict of fields
        :meth:`from_dict`; anything else a TypeError naming ``what`` (the argument)."""
        if params is None:
            return cls()
        if isinstance(params, Mapping):
            return cls.from_dict(params)
        require_type(params, cls, what, "FilterParams(...) or a dict of its fields")
        return params

    def validate(self) -> None:
        """Raise :class:`LocalizationError` on inconsistent values: noise and drift not
        negative, ranges increasing, counts and scales positive. (Every number was checked a
        number on construction: NaN nowhere, infinite only where :data:`UNBOUNDED_OK`
        allows, whole where a count is expected.)"""
        for name in NOT_NEGATIVE:
            if getattr(self, name) < 0:
                raise LocalizationError(f"{name} must be >= 0, got {getattr(self, name)}")
        for name in ("genome_a_range", "genome_b_range", "step_length_range_m"):
            lo, hi = getattr(self, name)
            if not lo < hi:
                raise LocalizationError(f"{name} must be (low, high) with low < high, got "
                                        f"{getattr(self, name)}")
        if self.n_particles < 1:
            raise LocalizationError(f"n_particles must be >= 1, got {self.n_particles}")
        for name in ("n_particles", "n_particles_start"):
            if getattr(self, name) > MAX_PARTICLES:  # 1e9 asked for tens of GB, then died
                raise LocalizationError(f"{name} must be at most {MAX_PARTICLES:,}, got "
                                        f"{getattr(self, name):,}")
        if self.recovery_max_half_width_m < self.recovery_half_width_m:
            raise LocalizationError(
                f"recovery_max_half_width_m ({self.recovery_max_half_width_m:g} m) must be at "
                f"least recovery_half_width_m ({self.recovery_half_width_m:g} m): recoveries "
                "widen from the one to the other")
        if self.step_model not in ("frequency", "weinberg"):
            raise LocalizationError(f"step_model must be 'frequency' or 'weinberg', got "
                                    f"{self.step_model!r}")
        if self.weight_mode not in WEIGHT_MODES:
            raise LocalizationError(f"weight_mode must be one of {WEIGHT_MODES}, got "
                                    f"{self.weight_mode!r}")
        for name in ("init_half_width_m", "recovery_half_width_m", "step_freq_nominal_hz",
                     "gaussian_sigma", "dtw_sigma", "radio_sigma_floor_m", "guide_sigma_m"):
            if not getattr(self, name) > 0:
                raise LocalizationError(f"{name} must be positive, got {getattr(self, name)}")
        for name in FEATURE_NAMES:
            f = getattr(self, name)
            if f.window < 1 or f.span < 1 or f.smooth < 1:
                raise LocalizationError(f"{name}: window, span and smooth must be >= 1")
            if not (f.award > 0 and f.threshold > 0):
                raise LocalizationError(f"{name}: award K and threshold T must be positive")
            if f.std_scale < 0:
                raise LocalizationError(f"{name}: std_scale must be >= 0")
        if not 0 <= self.radio_inject_fraction <= 1:
            raise LocalizationError("radio_inject_fraction must be in [0, 1]")
        if self.radio_inject_rule not in ("distance", "fit"):
            raise LocalizationError(f"radio_inject_rule must be 'distance' or 'fit', got "
                                    f"{self.radio_inject_rule!r}")
        if not 0 < self.radio_fit_slow < self.radio_fit_fast <= 1:
            raise LocalizationError("radio rates: need 0 < radio_fit_slow < radio_fit_fast <= 1")
        if not 0 <= self.radio_outlier < 1:
            raise LocalizationError("radio_outlier must be in [0, 1)")
        if self.radio_guide not in ("align", "fixes"):
            raise LocalizationError(f"radio_guide must be 'fixes' or 'align', got "
                                    f"{self.radio_guide!r}")

    @property
    def step_feature_nominal(self) -> float:
        """Nominal input ``F`` of the step-length model."""
        return self.step_freq_nominal_hz if self.step_model == "frequency" else \
            self.weinberg_nominal

    @classmethod
    def paper_params(cls, **overrides) -> FilterParams:
        """The papers' configuration: W = 3, K = 70, T = 0.05 on strength, azimuth and polar
        (the latter two on UFH steps), 300 particles, radio only for the start."""
        p = cls(n_particles_start=0, radio_update=False, radio_inject_fraction=0.0,
                strength=FeatureParams(window=3, award=70.0, threshold=0.05),
                azimuth=FeatureParams(window=3, award=70.0, threshold=0.05),
                polar=FeatureParams(window=3, award=70.0, threshold=0.05))
        # a feature given as a dict changes the papers' feature, not the default one
        features = {k: v for k, v in overrides.items()
                    if k in FEATURE_NAMES and isinstance(v, Mapping)}
        rest = {k: v for k, v in overrides.items() if k not in features}
        return replace(p, **rest).with_features(**features)

    def with_features(self, **changes) -> FilterParams:
        """Copy with feature parameters changed, e.g. ``with_features(strength={"window": 5})``."""
        kw = {k: _feature(k, getattr(self, k) if k in FEATURE_NAMES else None, v)
              for k, v in changes.items()}
        return replace(self, **kw)

    def to_json(self) -> str:
        return json.dumps(asdict(self), sort_keys=True)

    @classmethod
    def from_dict(cls, d: Mapping) -> FilterParams:
        """FilterParams from a dict of fields (``to_json``'s, or some of them): a feature's
        dict changes that feature's defaults (``{"strength": {"window": 5}}`` keeps the
        strength threshold of 0.5); an unknown field is a LocalizationError naming it."""
        d = dict(d)
        unknown = sorted(set(d) - {f.name for f in fields(cls)})
        if unknown:
            raise LocalizationError(f"unknown filter parameter(s) {', '.join(map(repr, unknown))}")
        return cls(**d)  # ranges given as lists (JSON's) are made tuples by _set_numbers


def _feature(name: str, base: FeatureParams | None, value: object) -> FeatureParams:
    """Feature ``name``'s parameters from ``value``: a FeatureParams, or a dict of fields
    changing ``base`` (the feature's defaults, or its parameters so far); a
    LocalizationError naming the feature for anything else, and for an unknown feature or
    field."""
    if base is None:
        raise LocalizationError(f"unknown feature {name!r}; the features are "
                                f"{', '.join(FEATURE_NAMES)}")
    if isinstance(value, FeatureParams):
        return value
    if not isinstance(value, Mapping):
        raise LocalizationError(f"{name} must be a FeatureParams or a dict of its fields, got "
                                f"{type(value).__name__}")
    unknown = sorted(set(value) - {f.name for f in fields(FeatureParams)})
    if unknown:
        raise LocalizationError(f"{name}: unknown feature parameter(s) "
                                f"{', '.join(map(repr, unknown))}; they are "
                                f"{', '.join(f.name for f in fields(FeatureParams))}")
    return replace(base, **value)
