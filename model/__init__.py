"""The learning core: motion math, data, the RSMT networks, training, evaluation and inference.

This package never imports ``service`` or ``clients``; they depend on it, not the reverse.
"""

__version__ = "0.1.0"
