"""pytest's settings for tests/python: the marker of the long runs (ctest SlowPythonTest)."""


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: a long physics run (make test-slow)")
