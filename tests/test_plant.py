"""The Plant protocol (linearize.plant): the shipped plants satisfy it, and check_plant names
what an object lacks or gets wrong."""
import pytest

from linearize.plant import REQUIRED, Plant, PlantProtocolError, check_plant, import_plant
from models.linear import LinearPlant
from models.turbofan import Turbofan


@pytest.mark.parametrize("cls", [LinearPlant, Turbofan])
def test_shipped_plants_satisfy_the_protocol(cls):
    plant = cls()
    assert isinstance(plant, Plant)
    assert check_plant(plant) is plant


class _Wrapped:
    """A plant's attributes copied onto a plain object, so single ones can be removed or broken."""

    def __init__(self, plant, drop=(), **override):
        for a in dir(plant):
            if not a.startswith("__") and a not in drop:
                setattr(self, a, getattr(plant, a))
        for k, v in override.items():
            setattr(self, k, v)


def test_check_plant_names_what_is_missing():
    with pytest.raises(PlantProtocolError, match="lacks trim, parameters"):
        check_plant(_Wrapped(LinearPlant(), drop=("trim", "parameters")))
    assert not isinstance(_Wrapped(LinearPlant(), drop=("units",)), Plant)
    assert set(REQUIRED) >= {"environment", "trim", "evaluate", "parameters", "units"}


def test_check_plant_names_what_is_wrong():
    lin = LinearPlant()
    with pytest.raises(PlantProtocolError, match="evaluate must be methods"):
        check_plant(_Wrapped(lin, evaluate=3.0))
    units = dict(lin.units)
    units.pop(lin.y_names[0])
    with pytest.raises(PlantProtocolError, match=f"no entry for {lin.y_names[0]}"):
        check_plant(_Wrapped(lin, units=units))
    with pytest.raises(PlantProtocolError, match="'continuous' or 'discrete'"):
        check_plant(_Wrapped(lin, time="hybrid"))
    with pytest.raises(PlantProtocolError, match="needs a dt"):
        check_plant(_Wrapped(lin, drop=("dt",), time="discrete"))
    with pytest.raises(PlantProtocolError, match="lo must be below hi"):
        check_plant(_Wrapped(lin, ranges={lin.y_names[0]: (2.0, 1.0)}))


def test_import_plant_suggests_a_close_name():
    with pytest.raises(PlantProtocolError, match="did you mean 'LinearPlant'"):
        import_plant("models.linear:LinearPlnt")
    with pytest.raises(PlantProtocolError, match="cannot be imported"):
        import_plant("models.no_such_module:X")
    assert import_plant("models.linear:LinearPlant") is LinearPlant
