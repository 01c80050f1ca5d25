"""The paper's published numbers, one place for every experiment and report that puts
vbl's results beside them (Asada, Uchibe, Hosoda: Tables 1-3)."""

from __future__ import annotations

__all__ = ["TABLE1", "TABLE2", "TABLE3"]

TABLE1 = {"goal": (1, 2, -0.001, 121), "ball": (2, 4, 0.232, 138),
          "random walk": (3, 6, 1.22, 232), "move to the ball": (3, 6, -0.463, 79)}
"""Table 1: l, n, log det R, AIC of the local predictive models, per observed agent."""

TABLE2 = {"shoot": {"current": 10.2, "cva": 78.5}, "pass": {"current": 9.8, "cva": 53.2}}
"""Table 2: success rates (%) of shooting and passing with current features or CVA state
vectors."""

TABLE3 = {"from the shooter": {"ball": (4, 4, 1.88, 284), "goal": (1, 3, -1.73, -817),
                               "passer": (5, 4, 3.43, 329)},
          "from the passer": {"ball": (4, 4, 1.36, 173), "shooter": (5, 4, 2.17, 284)}}
"""Table 3: l, n, log det R, AIC with noisy features, per observer and observed agent."""
