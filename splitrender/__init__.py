"""splitrender: split-rendering streaming for XR and thin clients."""

__version__ = "0.1.0"
