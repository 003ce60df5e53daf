FROM python:3.11-slim
WORKDIR /srv/conforma
COPY pyproject.toml README.md ./
COPY app app
COPY hardware hardware
COPY migrations migrations
COPY web web
RUN pip install --no-cache-dir -e '.[scale]'
ENV CONFORMA_DATA_DIR=/data CONFORMA_HOST=0.0.0.0
VOLUME /data
EXPOSE 8000 8080
CMD ["conforma", "serve"]
