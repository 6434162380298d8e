"""HTTP API (FastAPI): ``create_app(settings)`` in ``api.app``. Never imports torch."""
