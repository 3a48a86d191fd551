"""tacbench: a benchmark harness for Tsallis reinforcement learning."""

from tacbench.errors import TacbenchError

__all__ = ["TacbenchError", "__version__"]
__version__ = "0.1.0"
