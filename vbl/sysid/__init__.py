"""vbl.sysid: batched CVA system identification with AIC order and lag selection.

Quick use::

    from vbl.sysid import CVAParams, identify
    res = identify(u, y)            # u (B, N, m), y (B, N, q); lag by the predictor AIC
    res.lag, res.n, res.logdet_R, res.aic, res.n_at_cap   # (B,) each
    model = res.model               # batched CVAModel: vmap its methods over the B axis
    identify(u, y, CVAParams(lag_rule="paper"))           # the lag rule of Sec. 3.1.2

Every public function computes in float64 (unless its params ask for float32) whether or not
``jax_enable_x64`` is on globally: ``import vbl`` sets no global JAX option, and each call
scopes float64 itself. See ``docs/sysid.md``, "Numerics: float64 and float32".
"""

from vbl.sysid.aic import aic, param_count
from vbl.sysid.cva import CVAFit, n_identifiable
from vbl.sysid.lag import Identification, OrderCapWarning, identify, select_lag
from vbl.sysid.model import CVAModel, History
from vbl.sysid.params import CVAParams
from vbl.sysid.sweep import fit_batch, fit_one, fit_select_batch
from vbl.sysid.validate import CollinearWarning, check_data, min_length

__all__ = ["CVAParams", "identify", "Identification", "CVAModel", "History", "CVAFit",
           "fit_one", "fit_batch", "fit_select_batch", "n_identifiable", "select_lag", "aic",
           "param_count", "check_data", "min_length", "OrderCapWarning", "CollinearWarning"]
