"""prtcore HTTP front (FastAPI). Arrives with the service issue; see DESIGN.md section 6.

Nothing here yet: the library and CLI (``prtcore/``) are the product today.
"""
