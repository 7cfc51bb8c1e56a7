%% The state of evatar_ha_instance (private to it and evatar_ha_serving):
%% the role, the pairing's rules and the output commit.
-record(inst, {id :: term(),
               me :: term(),
               config :: evatar_pairing_logic:config(),
               logic :: evatar_pairing_logic:state() | undefined,
               commit = evatar_ha_commit:new(0) :: evatar_ha_commit:state(),
               role = starting :: starting | active | handing_over | standby | fenced,
               %% Standby and starting: its active; active: its standby.
               active :: term(),
               standby :: term(),
               watching = false :: boolean(),   % the active is monitored
               active_lost = false :: boolean(),
               placing = false :: boolean(),
               standby_node :: node() | undefined,
               core = evatar_ha_core:new() :: evatar_ha_core:state(),
               start :: evatar_ha_role_machine:starting() | undefined,
               reconfirming = false :: boolean(),
               %% Won again after a fence, keeping the standby: it has not
               %% yet confirmed the snapshot with the new claim.
               claiming = false :: boolean()}).
