"""The web viewer (issue 19): a static WebGL2 page over a bundle, package data under
``static/`` (``index.html``, ``viewer.js``, ``runtime.js`` and three.js r187, vendored by
``scripts/vendor_three.sh``), served on 127.0.0.1 by :mod:`prtcore.viewer.server`
(``prtcore view DIR``) and by the bake service at ``/v1/bakes/{id}/viewer``.
"""
