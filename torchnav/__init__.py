"""torchnav: batched, differentiable mobile-robot navigation in pure PyTorch."""

__version__ = "0.1.0"
