"""Domain logic of the shore: plain functions over a database session, tested without HTTP."""
