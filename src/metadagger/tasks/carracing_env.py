"""PLACEHOLDER: replaced by the fast-rendering base env."""
from gymnasium.envs.box2d.car_racing import CarRacing


class CarRacingFast(CarRacing):
    pass
