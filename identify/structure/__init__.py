"""Model structure determination (``identify structure``): stepwise regression with orthogonal
functions in equation error, then backward elimination in output error (:mod:`.search`)."""
from .prune import Prune
from .search import StructureSearch

__all__ = ["StructureSearch", "Prune"]
