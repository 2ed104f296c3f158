"""lpv_sysid.ident"""
