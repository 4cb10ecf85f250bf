"""The operator console: a web page that shows a running swarm and steers S by dragging it.

console.model (sans-IO state model), console.access (token and request checks),
console.steer_input (the page's steering requests), console.server (aiohttp + Zenoh shell,
``covswarm console``), static/ (the page, every asset shipped here).
"""
