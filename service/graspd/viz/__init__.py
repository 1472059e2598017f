"""graspd.viz: pictures for people: grasp plots (matplotlib) and the browser viewer (plotly page)."""
