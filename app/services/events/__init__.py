"""Events raised by the pipelines: list, acknowledge, comment, close."""
