"""prtcore.emitters."""
