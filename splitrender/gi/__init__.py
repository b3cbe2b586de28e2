"""Streaming global illumination to thin clients: the ``probes`` method's probe stream (:mod:`.stream`).

The DDGI probes themselves are the renderer's (:mod:`splitrender.render.ddgi`): every method's shading and
the ground truth share them.
"""
