# One image for both services: the SITL stub and the companion (see docker-compose.yml), plus a
# headless MAVProxy for the optional GCS service. No GUI: on Linux MAVProxy's own requirements
# pull its map / 3-D stack (vtk, opencv-python, quantized-mesh-tile, several hundred MB), which
# the console never imports, so MAVProxy goes in without them and with the requirements it has
# everywhere (its METADATA's unconditional Requires-Dist; tests/test_compose.py checks the list),
# and without its Cesium web-map module (114 MB of JavaScript for a browser GUI).
FROM python:3.11-slim
WORKDIR /app
COPY pyproject.toml README.md ./
COPY uav_model ./uav_model
COPY companion ./companion
COPY sim_bridge ./sim_bridge
COPY missions ./missions
RUN pip install --no-cache-dir . \
 && pip install --no-cache-dir --no-deps "MAVProxy>=1.8.70" \
 && pip install --no-cache-dir "pymavlink>=2.4.38" "defusedxml>=0.7.1" "pyserial>=3.0" numpy pynmeagps \
 && rm -rf "$(python -c 'import MAVProxy, os; print(os.path.dirname(MAVProxy.__file__))')/modules/mavproxy_cesium"
# 14540+i: vehicle API links (UDP), 14550: GCS link (UDP)
EXPOSE 14540/udp 14541/udp 14550/udp
CMD ["companion", "--help"]
