"""Shared fixtures: one headless GL renderer per test session (EGL through Mesa on CI)."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def renderer():
    from splitrender.render import Renderer

    return Renderer()


@pytest.fixture(scope="session")
def gl(renderer):
    return renderer.ctx
