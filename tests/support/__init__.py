"""Test doubles and tools shared by the test suites (on the path through pyproject's pythonpath)."""
