"""prtcore.scenes."""
