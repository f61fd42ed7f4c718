"""prtcore.intake."""
