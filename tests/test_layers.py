"""The layers import one way: driver → tracker → tools, with sim under the driver and the
test fixtures (testing) on top (docs/architecture.md). Read from the code's own imports with
grimp (the graph import-linter uses), so a lazy import inside a function counts as much as
one at the top of a module."""

from __future__ import annotations

import itertools

import grimp
import pytest

from tofcut.tools.cli import COMMANDS

FORBIDDEN = [
    ("tofcut.driver", "tofcut.sim"),
    ("tofcut.driver", "tofcut.tracker"),
    ("tofcut.driver", "tofcut.tools"),
    ("tofcut.tracker", "tofcut.sim"),
    ("tofcut.tracker", "tofcut.tools"),
    ("tofcut.sim", "tofcut.tracker"),
    ("tofcut.sim", "tofcut.tools"),
    # inside tools: the pipeline is under everything that runs on it, commands are on top
    ("tofcut.tools.pipeline", "tofcut.tools.commands"),
    ("tofcut.tools.pipeline", "tofcut.tools.bench"),
    ("tofcut.tools.pipeline", "tofcut.tools.evaluation"),
    ("tofcut.tools.pipeline", "tofcut.tools.experiments"),
    ("tofcut.tools.bench", "tofcut.tools.commands"),
    ("tofcut.tools.evaluation", "tofcut.tools.commands"),
    ("tofcut.tools.experiments", "tofcut.tools.commands"),
    # batches run the steps that commands and evaluation give them, knowing none of them
    ("tofcut.tools.pipeline", "tofcut.tools.batch"),
    ("tofcut.tools.batch", "tofcut.tools.commands"),
    ("tofcut.tools.batch", "tofcut.tools.evaluation"),
    # testing (the pytest plugin) is on top, beside the commands: nothing imports it, and it
    # opens cameras by the pipeline's source names, not through a command or the tracker
    ("tofcut.driver", "tofcut.testing"),
    ("tofcut.sim", "tofcut.testing"),
    ("tofcut.tracker", "tofcut.testing"),
    ("tofcut.tools", "tofcut.testing"),
    ("tofcut.testing", "tofcut.tracker"),
    ("tofcut.testing", "tofcut.tools.commands"),
    ("tofcut.testing", "tofcut.tools.bench"),
    ("tofcut.testing", "tofcut.tools.evaluation"),
    ("tofcut.testing", "tofcut.tools.experiments"),
]

COMMAND_MODULES = sorted(module for module, _ in COMMANDS.values())


@pytest.fixture(scope="module")
def graph() -> grimp.ImportGraph:
    return grimp.build_graph("tofcut")


def test_the_graph_sees_the_imports_that_are_allowed(graph):
    """The checks below could not fail if the graph saw no imports at all."""
    for importer, imported in [
        ("tofcut.tools", "tofcut.tracker"),
        ("tofcut.tracker", "tofcut.driver"),
        ("tofcut.sim", "tofcut.driver"),
        ("tofcut.tools.commands", "tofcut.tools.pipeline"),
        ("tofcut.tools.bench", "tofcut.tools.pipeline"),
        ("tofcut.tracker.paper", "tofcut.tracker.components_kernels"),
        ("tofcut.tools.commands.live", "tofcut.tools.commands.tracking"),
        ("tofcut.testing", "tofcut.tools.pipeline"),
        ("tofcut.testing", "tofcut.sim"),
    ]:
        assert graph.chain_exists(importer=importer, imported=imported, as_packages=True)


@pytest.mark.parametrize(("importer", "imported"), FORBIDDEN)
def test_no_layer_imports_upwards_or_sideways(graph, importer, imported):
    chains = graph.find_shortest_chains(importer=importer, imported=imported, as_packages=True)
    assert not chains, f"{importer} reaches {imported}: " + "; ".join(
        " → ".join(chain) for chain in sorted(chains)
    )


def test_no_tracker_module_imports_the_papers_segmentation(graph):
    """The multi-object tracker does not use the paper's single-target segmentation: no module
    of `tofcut.tracker` outside `tracker.paper` reaches it (the paper takes the tracker's
    neighbourhood and union-find, the other way)."""
    paper = "tofcut.tracker.paper"
    tracker = sorted(graph.find_children("tofcut.tracker") - {paper})
    assert {"tofcut.tracker.tracker", "tofcut.tracker.roster", "tofcut.tracker.cut"} < set(tracker)
    reached = [
        " → ".join(chain)
        for module in tracker
        for chain in sorted(graph.find_shortest_chains(importer=module, imported=paper))
    ]
    assert not reached, "the tracker reaches the paper: " + "; ".join(reached)


def test_no_command_imports_another(graph):
    """What two commands share lives in a module that is not a command (`commands.tracking`,
    the pipeline), so each command can change without moving another."""
    assert len(COMMAND_MODULES) == len(COMMANDS) > 1
    reached = [
        f"{a} → {b}"
        for a, b in itertools.permutations(COMMAND_MODULES, 2)
        if graph.chain_exists(importer=a, imported=b)
    ]
    assert not reached, "commands import commands: " + "; ".join(reached)
