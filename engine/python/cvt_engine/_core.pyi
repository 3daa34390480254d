# The extension cvt_engine._core: use the package cvt_engine (its __init__.pyi types the
# public calls). The errors and the configuration type are re-exported there.
from typing import Any

version: str

class ConfigError(ValueError):
    key: str
    value: str
    reason: str

class BlowUpError(RuntimeError): ...
class OutputError(OSError): ...

class Config:
    @property
    def toml(self) -> str: ...

def __getattr__(name: str) -> Any: ...
