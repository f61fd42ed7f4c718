"""prtcore.core."""
