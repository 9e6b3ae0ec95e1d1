"""What several test files share: case builders, solved scenes and the checks reached only by tests.

Importable as ``support`` from any test (``tests/`` is on ``sys.path`` through ``tests/conftest.py``).
"""
