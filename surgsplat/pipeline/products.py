"""What a run yields after training beside its checkpoint: files in the run folder that the
components of its method call for, made once training ends (`surgsplat train`, a batch job) and
iterated over here without the pipeline naming them.

surgsplat's own products are declared as entry points (BUILT_IN_PRODUCTS: the tool's
articulation, pipeline/articulate.py); installed packages add theirs through the entry-point
group `surgsplat.products` (`surgsplat.plugins`), each a `RunProduct`.
"""

from __future__ import annotations

import functools
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from importlib.metadata import EntryPoint

from surgsplat.model.dynamic import SplatModel
from surgsplat.plugins import load_extensions
from surgsplat.train.run import TrainedRun

PRODUCT_GROUP = "surgsplat.products"
"""The entry-point group through which an installed package adds products (an entry point's
value is a `RunProduct`)."""
BUILT_IN_PRODUCTS = (
    EntryPoint("articulation", "surgsplat.pipeline.articulate:ARTICULATION", PRODUCT_GROUP),)
"""surgsplat's own products, in the order they are made."""


@dataclass(frozen=True)
class RunProduct:
    """One product of a trained run."""

    name: str
    """What it is, in the user's words ("articulation")."""
    applies: Callable[[SplatModel], bool]
    """Whether a run of this model gets it (e.g. whether a component provides a capability)."""
    make: Callable[[TrainedRun], str]
    """Makes it and writes it into the run folder; one line for the user. SurgsplatError when
    it cannot be made for this run."""


@functools.cache
def run_products() -> tuple[RunProduct, ...]:
    """Every registered product, the built-in ones first; an installed one that cannot be
    loaded is left out with a warning (loaded on first use: a product's module may import this
    one)."""
    products, unloadable = load_extensions(PRODUCT_GROUP, BUILT_IN_PRODUCTS, RunProduct)
    for name, error in unloadable.items():
        warnings.warn(f"product {name!r} is not made: {error}", RuntimeWarning, stacklevel=2)
    return tuple(products.values())


def products_of(model: SplatModel) -> list[RunProduct]:
    """The products a run of `model` gets."""
    return [product for product in run_products() if product.applies(model)]
