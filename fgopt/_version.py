"""The package version, in the bottom layer so generated-code caches can key on it."""

__version__ = "0.1.0"
