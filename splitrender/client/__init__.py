"""Live headless client: receive, decode, display, record; scoring of recordings."""
