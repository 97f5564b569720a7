"""chizu service: FastAPI app, Prolog bridge, store and CLI."""
