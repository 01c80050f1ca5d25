"""Parameters of CVA identification (Section 3.1.1-3.1.2 of the paper).

All options of :func:`vbl.sysid.identify` live in :class:`CVAParams`; see ``docs/sysid.md``.
"""

from __future__ import annotations

from flax import struct

from vbl.params import ParamError, param

__all__ = ["CVAParams", "METHODS", "PARAM_COUNTS", "DTYPES", "LAG_RULES"]

LAG_RULES = ("predictor", "paper")
METHODS = ("projected", "paper")
PARAM_COUNTS = ("larimore", "sippy")
DTYPES = ("float64", "float32")


@struct.dataclass
class CVAParams:
    """Options of batched CVA identification with AIC order and lag selection."""

    lag: int = param(0, doc="past lag l of the stack p(t); 0 selects l per data set by "
                     "lag_rule among l = 1 .. lag_max", source="P/C", static=True, ge=0)
    lag_rule: str = param("predictor", doc="lag selection when lag = 0: 'predictor' "
                          "(default): l = lag_max, lag_max - lag_step, ... down to lag_min on "
                          "one common sample window; n* minimises the order criterion pooled "
                          "over these lags, sum_l [N_e log det R_l(n) + order_penalty "
                          "lambda(n)]; l* minimises the AIC of the whole one-step predictor "
                          "at n*, Eq. (6) plus 2 n* l (m+q) for the state map's coefficients "
                          "(both the same in any units); 'paper': the rule of Sec. 3.1.2 "
                          "(l = 1 .. lag_max; stop at the first l with log det R < "
                          "logdet_stop, else while AIC decreases; depends on the units of y)",
                          source="C", static=True, choices=LAG_RULES)
    lag_min: int = param(2, doc="lag_rule='predictor' only: smallest lag tried and pooled "
                         "(l = 1 identifies at most min(m+q, 2q) states and would cap n*)",
                         static=True, ge=1)
    lag_max: int = param(6, doc="largest lag the lag rule tries", static=True, ge=1)
    lag_step: int = param(3, doc="lag_rule='predictor' only: the lags tried are lag_max, "
                          "lag_max - lag_step, ... down to lag_min (default l = 6, 3: "
                          "neighbouring lags carry nearly the same order evidence: see the "
                          "order recovery measured in docs/sysid.md)",
                          static=True, ge=1)
    order_penalty: float = param(3.0, doc="lag_rule='predictor' only: penalty per parameter "
                                 "of lambda(n) in the pooled order criterion (3: AIC3; "
                                 "measured to recover the order more often than Eq. (6)'s 2)",
                                 gt=0.0)
    horizon: int = param(0, doc="future horizon k of the stack f(t); 0 means k = 2l "
                         "(measured: recovers the order more often than k = l)",
                         static=True, ge=0)
    n_max: int = param(0, doc="largest state order n swept; 0 means all identifiable orders "
                       "min(l(m+q), kq)", static=True, ge=0)
    n_min: int = param(1, doc="smallest state order n considered by the AIC argmin",
                       static=True, ge=0)
    method: str = param("projected", doc="'projected': future inputs projected out of past "
                        "and future stacks before the canonical correlations (Larimore); "
                        "'paper': the plain recipe of Eqs. (2)-(5)", static=True,
                        choices=METHODS)
    param_count: str = param("larimore", doc="AIC parameter count lambda(n): 'larimore' "
                             "n(2q+m)+qm+q(q+1)/2, 'sippy' n(q+m)+qm", static=True,
                             choices=PARAM_COUNTS)
    demean: bool = param(True, doc="remove each channel's mean before identification",
                         static=True)
    standardize: bool = param(True, doc="divide each channel by its standard deviation "
                              "(log det R then means the same in any units)", static=True)
    dtype: str = param("float64", doc="floating type of the identification arithmetic",
                       static=True, choices=DTYPES)
    reg: float = param(1e-10, doc="regularisation floor (float64): eps * mean diagonal added "
                       "to every covariance before a Cholesky factorisation", ge=0.0, lt=1.0)
    reg_float32: float = param(1e-6, doc="regularisation floor used when dtype='float32'",
                               ge=0.0, lt=1.0)
    logdet_stop: float = param(0.0, doc="lag_rule='paper' only: stop growing l once "
                               "log det R < this", source="P")
    const_tol: float = param(1e-9, doc="a channel whose std <= const_tol * max|x| is "
                             "constant (error)", ge=0.0, lt=1.0)
    collinear_tol: float = param(1e-8, doc="warn when two channels of u (or of y) have "
                                 "|correlation| >= 1 - collinear_tol, or the channels' "
                                 "correlation matrix has an eigenvalue below it (collinear)",
                                 ge=0.0, lt=1.0)
    min_samples_factor: float = param(2.0, doc="require N-k-l+1 >= this x (l+k)(m+q) "
                                      "samples in the covariance estimates", ge=1.0)

    def check(self) -> None:
        if self.lag > self.lag_max and self.lag != 0:
            raise ParamError(f"lag={self.lag} exceeds lag_max={self.lag_max}; raise lag_max "
                             "or lower lag")
        if self.n_max and self.n_min > self.n_max:
            raise ParamError(f"n_min={self.n_min} exceeds n_max={self.n_max}")

    def lags(self) -> tuple[int, ...]:
        """Lags tried, ascending: ``(lag,)`` when fixed; lag_rule 'predictor': ``lag_max,
        lag_max - lag_step, ...`` down to ``lag_min`` (at least ``lag_max``); 'paper':
        ``1 .. lag_max``."""
        if self.lag > 0:
            return (self.lag,)
        if self.lag_rule == "predictor":
            first = min(self.lag_min, self.lag_max)
            return tuple(range(self.lag_max, first - 1, -self.lag_step))[::-1]
        return tuple(range(1, self.lag_max + 1))

    def horizon_for(self, lag: int) -> int:
        """Future horizon k used with past lag ``lag``."""
        return self.horizon if self.horizon > 0 else 2 * lag

    def floor(self) -> float:
        """Regularisation floor of the chosen dtype."""
        return self.reg_float32 if self.dtype == "float32" else self.reg
