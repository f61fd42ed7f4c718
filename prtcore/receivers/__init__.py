"""prtcore.receivers."""
