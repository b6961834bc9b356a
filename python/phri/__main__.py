"""``python -m phri ...``: the ``phri`` command line."""

from __future__ import annotations

from phri.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
