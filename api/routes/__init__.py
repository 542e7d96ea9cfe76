"""HTTP routers, one module per resource, mounted under ``/api/v1`` by :func:`api.app.create_app`."""
