"""Discovery: find where a model and a recording differ, name the physics the model leaves
out, model it and show the held-out improvement (issue 6; docs/discovery.md).

* :mod:`~cablesvc.models.terms`: the library of named physics terms (one class each);
* :mod:`~cablesvc.discover.locate`: which cables, time segments and state regions;
* :mod:`~cablesvc.discover.select`: fitting and held-out forward selection (an exact baseline);
* :mod:`~cablesvc.discover.screen`: the block-level screen (an identified, imperfect baseline);
* :mod:`~cablesvc.discover.evidence`: block-level tests (the block, not the tick, is the unit);
* :mod:`~cablesvc.discover.pipeline`: :func:`discover` end to end;
* :mod:`~cablesvc.discover.report`: JSON, HTML and figures.
"""

from cablesvc.discover.pipeline import Discovery, DiscoveryError, Finding, discover
from cablesvc.discover.screen import BlockScreen
from cablesvc.discover.select import ForwardSelector, SelectOptions
from cablesvc.models.terms import LIBRARY, Signals, Term, library, register

__all__ = ["BlockScreen", "Discovery", "DiscoveryError", "Finding", "ForwardSelector", "LIBRARY", "SelectOptions", "Signals",
           "Term", "discover", "library", "register"]
