"""tofcut: time-of-flight camera driver, emulator and graph-cut tracker."""

__version__ = "0.1.0"
