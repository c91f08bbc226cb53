"""LunarLander from pixels as a metadagger task (an example of a task in a package of its own)."""

from metadagger_lunarlander.task import LanderPixels, LunarLanderTask

__all__ = ["LanderPixels", "LunarLanderTask"]
