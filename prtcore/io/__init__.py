"""prtcore.io."""
