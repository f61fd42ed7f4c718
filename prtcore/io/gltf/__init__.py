"""prtcore.io.gltf."""
