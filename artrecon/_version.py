"""The package version, in a module of its own: the stages record it without importing the
package's public entry point (which imports them)."""

__version__ = "0.1.0"
