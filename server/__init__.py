"""The shore control center: FastAPI app, link engine, storage, operator's screen."""
