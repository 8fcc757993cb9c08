"""MkDocs hook: Sphinx cross-reference roles in calib's docstrings read as plain code on the site.

calib's numpydoc docstrings name other objects the Sphinx way (``:class:`calib.core.spectra.Spectrum```),
which mkdocstrings renders as the role's name followed by the code. This drops the role's name
(and Sphinx's ``~`` shortening prefix) so that only the code remains.
"""

from __future__ import annotations

import re
from typing import Any

_ROLE = re.compile(r":(?:class|func|meth|mod|data|attr|exc|obj|const):(<code>)~?")


def on_page_content(html: str, **kwargs: Any) -> str:
    """Remove ``:role:`` prefixes in front of inline code."""
    return _ROLE.sub(r"\1", html)
