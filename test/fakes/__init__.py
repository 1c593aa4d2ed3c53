"""Emulated devices for tests."""
