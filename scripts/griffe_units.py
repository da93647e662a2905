"""A griffe extension for odomgym's documentation site (``mkdocs.yml``: ``extensions``).

It adapts the rendered copy of each docstring (the source is untouched) to Markdown:

* units in brackets after a value — ``in [min, max] [m]`` — would read as a reference-style
  link ``[text] [ref]`` to an anchor named ``m`` (mkdocs-autorefs then fails the strict build):
  the second bracket of every such pair is escaped (``] [`` → ``] \\[``);
* Sphinx roles (``:class:`~odomgym.robot.RobotSpec```, ``:func:``, ``:mod:`` …), which the
  docstrings use for ``help()`` readers, become inline code (```odomgym.robot.RobotSpec```).
"""

from __future__ import annotations

import re
from typing import Any

import griffe

_PAIR = re.compile(r"\] \[")
_ROLE = re.compile(r":(?:class|mod|func|meth|data|attr|exc|obj|const):`~?([^`]+)`")


class UnitBrackets(griffe.Extension):
    """Escape ``] [`` and turn Sphinx roles into inline code in every docstring."""

    def on_object(self, *, obj: griffe.Object, loader: griffe.GriffeLoader, **kwargs: Any) -> None:
        del loader, kwargs
        if obj.docstring is None:
            return
        text = _PAIR.sub(r"] \\[", obj.docstring.value)
        obj.docstring.value = _ROLE.sub(r"`\1`", text)
