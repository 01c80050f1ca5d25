"""vbl.sysid: batched CVA system identification with AIC order and lag selection.

Quick use::

    from vbl.sysid import CVAParams, identify
    res = identify(u, y)            # u (B, N, m), y (B, N, q)
    res.lag, res.n, res.logdet_R, res.aic   # (B,) each
    model = res.model               # batched CVAModel: vmap its methods over the B axis

See ``docs/sysid.md``.
"""

from vbl.sysid.aic import aic, param_count
from vbl.sysid.cva import CVAFit, fit_batch, fit_one, n_identifiable
from vbl.sysid.lag import Identification, identify, select_lag
from vbl.sysid.model import CVAModel, History
from vbl.sysid.params import CVAParams
from vbl.sysid.validate import check_data, min_length

__all__ = ["CVAParams", "identify", "Identification", "CVAModel", "History", "CVAFit",
           "fit_one", "fit_batch", "n_identifiable", "select_lag", "aic", "param_count",
           "check_data", "min_length"]
