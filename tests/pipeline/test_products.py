"""Products after training (surgsplat.pipeline.products): registered, not named by the
pipeline, and each made for the models whose components call for it."""

from types import SimpleNamespace

from surgsplat.model.capabilities import ToolMotion
from surgsplat.pipeline.products import BUILT_IN_PRODUCTS, RunProduct, products_of, run_products


class FakeModel:
    """A model whose components provide the given capabilities."""

    def __init__(self, *capabilities: type):
        self.capabilities = capabilities

    def find(self, capability: type):
        return SimpleNamespace() if capability in self.capabilities else None


def test_the_tool_articulation_is_a_built_in_product_of_models_with_a_tool_field():
    products = run_products()
    assert isinstance(products[0], RunProduct) and products[0].name == "articulation"
    assert [e.name for e in BUILT_IN_PRODUCTS] == ["articulation"]
    assert products_of(FakeModel(ToolMotion))[:1] == [products[0]]
    assert products[0] not in products_of(FakeModel())
