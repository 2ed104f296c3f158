"""Stand-in for ``rclpy.parameter`` (Jazzy typing rules)."""

import array
from enum import Enum

from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue

PARAMETER_SEPARATOR_STRING = "."


class Parameter:
    class Type(Enum):
        NOT_SET = ParameterType.PARAMETER_NOT_SET
        BOOL = ParameterType.PARAMETER_BOOL
        INTEGER = ParameterType.PARAMETER_INTEGER
        DOUBLE = ParameterType.PARAMETER_DOUBLE
        STRING = ParameterType.PARAMETER_STRING
        BYTE_ARRAY = ParameterType.PARAMETER_BYTE_ARRAY
        BOOL_ARRAY = ParameterType.PARAMETER_BOOL_ARRAY
        INTEGER_ARRAY = ParameterType.PARAMETER_INTEGER_ARRAY
        DOUBLE_ARRAY = ParameterType.PARAMETER_DOUBLE_ARRAY
        STRING_ARRAY = ParameterType.PARAMETER_STRING_ARRAY

        @classmethod
        def from_parameter_value(cls, parameter_value):
            if parameter_value is None:
                return Parameter.Type.NOT_SET
            if isinstance(parameter_value, bool):
                return Parameter.Type.BOOL
            if isinstance(parameter_value, int):
                return Parameter.Type.INTEGER
            if isinstance(parameter_value, float):
                return Parameter.Type.DOUBLE
            if isinstance(parameter_value, str):
                return Parameter.Type.STRING
            if isinstance(parameter_value, (list, tuple, array.array)):
                if all(isinstance(v, bytes) for v in parameter_value):
                    return Parameter.Type.BYTE_ARRAY
                if all(isinstance(v, bool) for v in parameter_value):
                    return Parameter.Type.BOOL_ARRAY
                if all(isinstance(v, int) for v in parameter_value):
                    return Parameter.Type.INTEGER_ARRAY
                if all(isinstance(v, float) for v in parameter_value):
                    return Parameter.Type.DOUBLE_ARRAY
                if all(isinstance(v, str) for v in parameter_value):
                    return Parameter.Type.STRING_ARRAY
                raise TypeError(
                    f"The given value is not a list of one of the allowed types "
                    f"'{parameter_value}'."
                )
            raise TypeError(
                f"The given value is not one of the allowed types '{parameter_value}'."
            )

        def check(self, parameter_value):
            T = Parameter.Type
            if self == T.NOT_SET:
                return parameter_value is None
            if self == T.BOOL:
                return isinstance(parameter_value, bool)
            if self == T.INTEGER:
                return isinstance(parameter_value, int)
            if self == T.DOUBLE:
                return isinstance(parameter_value, float)
            if self == T.STRING:
                return isinstance(parameter_value, str)
            seq = isinstance(parameter_value, (list, tuple, array.array))
            if self == T.BYTE_ARRAY:
                return seq and all(isinstance(v, bytes) and len(v) == 1 for v in parameter_value)
            if self == T.BOOL_ARRAY:
                return seq and all(isinstance(v, bool) for v in parameter_value)
            if self == T.INTEGER_ARRAY:
                return seq and all(isinstance(v, int) for v in parameter_value)
            if self == T.DOUBLE_ARRAY:
                return seq and all(isinstance(v, float) for v in parameter_value)
            if self == T.STRING_ARRAY:
                return seq and all(isinstance(v, str) for v in parameter_value)
            return False

    @classmethod
    def from_parameter_msg(cls, param_msg):
        return cls(
            param_msg.name,
            Parameter.Type(param_msg.value.type),
            parameter_value_to_python(param_msg.value),
        )

    def __init__(self, name, type_=None, value=None):
        if type_ is None:
            type_ = Parameter.Type.from_parameter_value(value)
        if not isinstance(type_, Parameter.Type):
            raise TypeError("type must be an instance of '{}'".format(repr(Parameter.Type)))
        if not type_.check(value):
            raise ValueError(f"Type '{type_}' and value '{value}' do not agree")
        self._type_ = type_
        self._name = name
        self._value = value

    @property
    def name(self):
        return self._name

    @property
    def type_(self):
        return self._type_

    @property
    def value(self):
        return self._value

    def get_parameter_value(self):
        T = Parameter.Type
        pv = ParameterValue(type=self._type_.value)
        if self._type_ == T.BOOL:
            pv.bool_value = self._value
        elif self._type_ == T.INTEGER:
            pv.integer_value = self._value
        elif self._type_ == T.DOUBLE:
            pv.double_value = self._value
        elif self._type_ == T.STRING:
            pv.string_value = self._value
        elif self._type_ == T.BYTE_ARRAY:
            pv.byte_array_value = list(self._value)
        elif self._type_ == T.BOOL_ARRAY:
            pv.bool_array_value = list(self._value)
        elif self._type_ == T.INTEGER_ARRAY:
            pv.integer_array_value = list(self._value)
        elif self._type_ == T.DOUBLE_ARRAY:
            pv.double_array_value = list(self._value)
        elif self._type_ == T.STRING_ARRAY:
            pv.string_array_value = list(self._value)
        return pv

    def to_parameter_msg(self):
        return ParameterMsg(name=self.name, value=self.get_parameter_value())

    def __repr__(self):
        return f"Parameter(name={self._name!r}, type_={self._type_}, value={self._value!r})"


def parameter_value_to_python(parameter_value):
    T = ParameterType
    t = parameter_value.type
    if t == T.PARAMETER_BOOL:
        return parameter_value.bool_value
    if t == T.PARAMETER_INTEGER:
        return parameter_value.integer_value
    if t == T.PARAMETER_DOUBLE:
        return parameter_value.double_value
    if t == T.PARAMETER_STRING:
        return parameter_value.string_value
    if t == T.PARAMETER_BYTE_ARRAY:
        return list(parameter_value.byte_array_value)
    if t == T.PARAMETER_BOOL_ARRAY:
        return list(parameter_value.bool_array_value)
    if t == T.PARAMETER_INTEGER_ARRAY:
        return list(parameter_value.integer_array_value)
    if t == T.PARAMETER_DOUBLE_ARRAY:
        return list(parameter_value.double_array_value)
    if t == T.PARAMETER_STRING_ARRAY:
        return list(parameter_value.string_array_value)
    if t == T.PARAMETER_NOT_SET:
        return None
    raise RuntimeError(f"unexpected parameter type {t}")


def parameter_dict_from_yaml_file(
    parameter_file, use_wildcard=False, target_nodes=None, namespace=""
):
    """``{name: ParameterMsg}`` for the nodes of a ``ros__parameters`` file (rclpy API)."""
    from rclpy._params_file import load_overrides
    from rclpy._params_file import read as _read

    data = _read(parameter_file)
    out = {}
    for node in target_nodes or list(data):
        for p in load_overrides(data, node.lstrip("/"), use_wildcard):
            out[p.name] = p.to_parameter_msg()
    return out
