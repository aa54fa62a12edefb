"""The varbot web API: FastAPI app, database models, blob store.

Never imports torch, pybullet, learning/ or sim/."""
