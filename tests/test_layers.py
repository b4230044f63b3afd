"""The layers import one way: driver → tracker → tools, with sim under the driver (README,
"Layout"). Read from the code's own imports with grimp (the graph import-linter uses), so a
lazy import inside a function counts as much as one at the top of a module."""

from __future__ import annotations

import grimp
import pytest

FORBIDDEN = [
    ("tofcut.driver", "tofcut.sim"),
    ("tofcut.driver", "tofcut.tracker"),
    ("tofcut.driver", "tofcut.tools"),
    ("tofcut.tracker", "tofcut.sim"),
    ("tofcut.tracker", "tofcut.tools"),
    ("tofcut.sim", "tofcut.tracker"),
    ("tofcut.sim", "tofcut.tools"),
]


@pytest.fixture(scope="module")
def graph() -> grimp.ImportGraph:
    return grimp.build_graph("tofcut")


def test_the_graph_sees_the_imports_that_are_allowed(graph):
    """The check below could not fail if the graph saw no imports at all."""
    for importer, imported in [
        ("tofcut.tools", "tofcut.tracker"),
        ("tofcut.tracker", "tofcut.driver"),
        ("tofcut.sim", "tofcut.driver"),
    ]:
        assert graph.chain_exists(importer=importer, imported=imported, as_packages=True)


@pytest.mark.parametrize(("importer", "imported"), FORBIDDEN)
def test_no_layer_imports_upwards_or_sideways(graph, importer, imported):
    chains = graph.find_shortest_chains(importer=importer, imported=imported, as_packages=True)
    assert not chains, f"{importer} reaches {imported}: " + "; ".join(
        " → ".join(chain) for chain in sorted(chains)
    )
