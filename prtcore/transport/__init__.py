"""prtcore.transport."""
