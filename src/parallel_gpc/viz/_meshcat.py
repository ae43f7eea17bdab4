"""meshcat imports in one place (meshcat 0.3.2 imports the deprecated ``zmq.eventloop.ioloop``)."""

import warnings

with warnings.catch_warnings():
    warnings.simplefilter("ignore", DeprecationWarning)
    import meshcat
    import meshcat.geometry as mg
    from meshcat.animation import Animation
    from meshcat.servers.tree import SceneTree
    from meshcat.servers.zmqserver import (
        VIEWER_HTML,
        VIEWER_ROOT,
        StaticFileHandlerNoCache,
        WebSocketHandler,
        ZMQWebSocketBridge,
    )
    from meshcat.visualizer import ViewerWindow

__all__ = ["meshcat", "mg", "Animation", "SceneTree", "VIEWER_HTML", "VIEWER_ROOT", "StaticFileHandlerNoCache",
           "WebSocketHandler", "ZMQWebSocketBridge", "ViewerWindow"]
