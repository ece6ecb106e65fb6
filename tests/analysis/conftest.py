from __future__ import annotations

import pytest


@pytest.fixture
def drawn_figures(monkeypatch):
    """The figures the drawing code closes, kept open for the test to look at, then closed."""
    import matplotlib.pyplot as plt

    close, kept = plt.close, []
    monkeypatch.setattr(plt, "close", kept.append)
    yield kept
    for fig in kept:
        close(fig)
