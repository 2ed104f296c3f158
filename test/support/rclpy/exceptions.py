"""Stand-in for ``rclpy.exceptions`` (Jazzy names and messages)."""


class NotInitializedException(Exception):
    def __init__(self, *args):
        Exception.__init__(self, "rclpy.init() has not been called", *args)


class NoTypeSupportImportedException(Exception):
    def __init__(self, *args):
        Exception.__init__(self, "no type_support imported", *args)


class NameValidationException(Exception):
    def __init__(self, name_type, name, error_msg, invalid_index):
        Exception.__init__(
            self, f"Invalid {name_type}: {error_msg}:\n  '{name}'\n   " + " " * invalid_index + "^"
        )


class InvalidNodeNameException(NameValidationException):
    def __init__(self, *args):
        NameValidationException.__init__(self, "node name", *args)


class InvalidNamespaceException(NameValidationException):
    def __init__(self, *args):
        NameValidationException.__init__(self, "namespace", *args)


class InvalidTopicNameException(NameValidationException):
    def __init__(self, *args):
        NameValidationException.__init__(self, "topic name", *args)


class InvalidServiceNameException(NameValidationException):
    def __init__(self, *args):
        NameValidationException.__init__(self, "service name", *args)


class ParameterException(Exception):
    def __init__(self, error_msg, parameters, *args):
        Exception.__init__(self, error_msg, parameters, *args)


class ParameterNotDeclaredException(ParameterException):
    def __init__(self, parameters, *args):
        ParameterException.__init__(
            self, "Invalid access to undeclared parameter(s)", parameters, *args
        )


class ParameterAlreadyDeclaredException(ParameterException):
    def __init__(self, parameters, *args):
        ParameterException.__init__(self, "Parameter(s) already declared", parameters, *args)


class InvalidParameterException(ParameterException):
    def __init__(self, parameter, *args):
        ParameterException.__init__(self, "Invalid parameter name", parameter, *args)


class InvalidParameterTypeException(ParameterException):
    def __init__(self, desired_parameter, expected_type, *args):
        ParameterException.__init__(
            self,
            f"Trying to set parameter '{desired_parameter._name}' to "
            f"'{desired_parameter._value}' of type '{desired_parameter._type_.name}', "
            f"expecting type '{expected_type}'",
            desired_parameter,
            *args,
        )


class InvalidParameterValueException(ParameterException):
    def __init__(self, parameter, value, reason, *args):
        ParameterException.__init__(
            self,
            "Invalid parameter value ({value}) for parameter. Reason: {reason}".format(
                value=value, reason=reason
            ),
            parameter,
            *args,
        )


class ParameterImmutableException(ParameterException):
    def __init__(self, parameters, *args):
        ParameterException.__init__(
            self, "Attempted to modify read-only parameter", parameters, *args
        )


class ParameterUninitializedException(ParameterException):
    def __init__(self, parameter_name, *args):
        ParameterException.__init__(
            self, f"The parameter '{parameter_name}' is not initialized", parameter_name, *args
        )


class ROSInterruptException(Exception):
    def __init__(self, *args):
        Exception.__init__(self, "rclpy.shutdown() has been called", *args)


class InvalidHandle(Exception):
    pass
