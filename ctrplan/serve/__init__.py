"""`ctrplan serve`: a local web app where the target moves and the path follows -- a planning session
(`session`), its JSON API (`api`), the page drawn with viser (`page`, `render`) and the one address
that serves both (`front`)."""
