"""prtcore.runtime."""
