"""Pictures of plans and flights; ``plotting`` is the only module that imports matplotlib."""
