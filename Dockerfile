# One image for both services: the SITL stub and the companion (see docker-compose.yml), plus
# MAVProxy (the `gcs` extra) for the optional headless GCS service.
FROM python:3.11-slim
WORKDIR /app
COPY pyproject.toml README.md ./
COPY uav_model ./uav_model
COPY companion ./companion
COPY sim_bridge ./sim_bridge
COPY missions ./missions
RUN pip install --no-cache-dir ".[gcs]"
# 14540+i: vehicle API links (UDP), 14550: GCS link (UDP)
EXPOSE 14540/udp 14541/udp 14550/udp
CMD ["companion", "--help"]
