"""The package version, in a module of its own so that modules inside :mod:`jaxcal` (model files,
exports, the command line) can name it without importing the package's front door."""

__version__ = "0.1.0"
