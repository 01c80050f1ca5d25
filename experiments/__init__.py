"""vbl's experiment scripts, one result each, installed as ``vbl.experiments``.

The registry imports each script by its path (``vbl list`` / ``vbl run NAME``); run one
directly with ``python experiments/NAME.py`` or ``vbl run NAME``."""
