"""Pictures of plans and flights: ``plotting`` (the only module that imports matplotlib), the live browser view
(``live``: the only module that imports aiohttp; ``feed``: what it shows) and the plan exports (``export``)."""

#: The live view's default port on 127.0.0.1 (``--view`` without a number). Here, not in ``live``, so that the
#: command line can show it without importing the server (asyncio, aiohttp) on every run.
DEFAULT_VIEW_PORT = 8765
