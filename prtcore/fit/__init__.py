"""prtcore.fit."""
