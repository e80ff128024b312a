FROM python:3.11-slim
WORKDIR /srv/fleethealth
COPY pyproject.toml README.md alembic.ini ./
COPY app ./app
COPY estimation ./estimation
COPY migrations ./migrations
COPY static ./static
RUN pip install --no-cache-dir .
ENV FLEETHEALTH_DATA_DIR=/var/lib/fleethealth
EXPOSE 8000
CMD ["fleethealth", "serve", "--host", "0.0.0.0", "--skip-migrate"]
