"""Wire formats of bulk data: PostgreSQL binary COPY and JSON numbers."""
