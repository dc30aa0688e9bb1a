"""Wire messages of the services: schemas (pydantic), the msgpack codec and the key table."""
