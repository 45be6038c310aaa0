"""The live view: a read-only subscriber that serves a page showing a run as it happens.

``poseidon view [--connect tcp/HOST:7447] [--listen 127.0.0.1:8080] [--foxglove PORT]`` over a
running deployment, ``poseidon view RUN.mcap`` over a finished run (time slider), and
``poseidon run ... --view [HOST:]PORT`` beside a replay or a live run.

- :mod:`services.viewer.model`: what the page shows, bounded (:class:`ViewModel`);
- :mod:`services.viewer.live`: the bus subscriber (Zenoh ring buffers, never slows the SLAM);
- :mod:`services.viewer.figures`: the per-service figures (rate, lag, gaps, restarts, latency);
- :mod:`services.viewer.sampler`: heavy keys (camera images) taken a few frames a second;
- :mod:`services.viewer.recording`: a recording at the slider's time;
- :mod:`services.viewer.server`: the HTTP server and why the page polls JSON snapshots;
- :mod:`services.viewer.foxglove_live`: the same streams over Foxglove's WebSocket protocol;
- :mod:`services.viewer.app`: the command's two modes;
- ``static/``: the page (hand-written HTML, CSS and canvas drawing; nothing from the network).
"""
