"""Commands on recorded data and files: ``bag`` (repair), ``replay``, ``report``, ``config``."""

from __future__ import annotations

__all__ = []
