"""The web viewer (issue 19): a static WebGL2 page over a bundle, package data under
``static/``: ``index.html``; ``viewer.js``, the page; ``runtime.js``, the PRT runtime from
``manifest.json`` alone (the reference engine integration); ``shaders.js``; ``reference.js``,
the error heat map's reference; three.js r187, vendored by ``scripts/vendor_three.sh``.
Served on 127.0.0.1 by :mod:`prtcore.viewer.server` (``prtcore view DIR``) and by the bake
service at ``/v1/bakes/{id}/viewer``.
"""
