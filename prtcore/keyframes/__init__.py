"""prtcore.keyframes."""
