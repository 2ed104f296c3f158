"""Stand-in for ``rclpy.callback_groups``."""


class CallbackGroup:
    def __init__(self):
        self.entities = set()

    def add_entity(self, entity):
        self.entities.add(id(entity))

    def has_entity(self, entity):
        return id(entity) in self.entities

    def can_execute(self, entity):
        return True


class MutuallyExclusiveCallbackGroup(CallbackGroup):
    pass


class ReentrantCallbackGroup(CallbackGroup):
    pass
