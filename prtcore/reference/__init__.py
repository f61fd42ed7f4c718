"""prtcore.reference."""
