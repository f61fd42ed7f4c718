"""Job-queue workers running prtcore bakes. Arrive with the service issue (DESIGN.md 6)."""
