# Images for the varbot processes; docker-compose.yml picks the target and the command.
#   target `api`:  the web API and migrations — no torch, no pybullet (the API never imports them).
#   target `full`: workers (training, robot) and the scene — everything in pyproject.toml.
# Stage `build-*` make a virtualenv; the runtime stages copy only that venv and the sources.
# Not built here: the development machines have no Docker engine.

FROM python:3.11-slim-bookworm AS sources
WORKDIR /src
COPY pyproject.toml README.md alembic.ini ./
COPY core ./core
COPY varbot ./varbot
COPY backend ./backend
COPY sim ./sim
COPY learning ./learning
COPY worker ./worker
COPY scene ./scene
COPY migrations ./migrations
COPY frontend ./frontend

FROM python:3.11-slim-bookworm AS build-full
ENV PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1
RUN apt-get update && apt-get install -y --no-install-recommends build-essential && rm -rf /var/lib/apt/lists/*
RUN python -m venv /opt/venv
ENV PATH=/opt/venv/bin:$PATH
COPY --from=sources /src /src
WORKDIR /src
# CPU wheels of torch keep the image small; use the default index on GPU machines.
RUN pip install --upgrade pip setuptools wheel \
 && pip install --extra-index-url https://download.pytorch.org/whl/cpu .

FROM python:3.11-slim-bookworm AS build-api
ENV PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1
RUN python -m venv /opt/venv
ENV PATH=/opt/venv/bin:$PATH
COPY --from=sources /src /src
WORKDIR /src
# The project without its heavy dependencies: every pinned requirement except the method's and the scene's.
RUN pip install --upgrade pip setuptools wheel \
 && python -c "import tomllib; heavy = ('torch', 'torchaudio', 'pybullet', 'opencv', 'viser', 'yourdfpy', 'mido', 'matplotlib', 'pyroomacoustics'); deps = tomllib.load(open('pyproject.toml', 'rb'))['project']['dependencies']; print('\n'.join(d for d in deps if not d.startswith(heavy)))" > /tmp/api-requirements.txt \
 && pip install -r /tmp/api-requirements.txt \
 && pip install --no-deps .

FROM python:3.11-slim-bookworm AS runtime-base
# PYTHONPATH: the sources under /app come first, so that the pages (/app/frontend) are found beside them.
ENV PYTHONUNBUFFERED=1 VARBOT_DATA_DIR=/data PATH=/opt/venv/bin:$PATH PYTHONPATH=/app
RUN useradd --create-home --uid 1000 varbot && mkdir -p /data && chown varbot /data
WORKDIR /app

FROM runtime-base AS api
COPY --from=build-api /opt/venv /opt/venv
COPY --from=build-api /src /app
USER varbot
EXPOSE 8000
CMD ["varbot", "api", "--host", "0.0.0.0", "--port", "8000"]

FROM runtime-base AS full
# libgomp for torch's CPU kernels; espeak-ng only if you rebuild corpora inside the container.
RUN apt-get update && apt-get install -y --no-install-recommends libgomp1 && rm -rf /var/lib/apt/lists/*
COPY --from=build-full /opt/venv /opt/venv
COPY --from=build-full /src /app
USER varbot
EXPOSE 8080
CMD ["varbot", "worker", "--queue", "training"]
