%% @doc Internal. Part of the role machine of `evatar_ha_instance', pure:
%% what each decision of `evatar_ha_core' means for the instance (take
%% over, step down or stop, release and place a standby, fence), and what
%% only a serving active does (place its standby, fence without a majority,
%% drop silent client links and hand the pairing over, carry out the
%% rebalancer's moves). Called by `evatar_ha_instance' only, with the same
%% view and decisions (docs/ha-design.md, section 12).
-module(evatar_ha_serving).

-export([core/3, core_ctx/2, step_down/3, stop/3, forget_standby/1, place/2, place_soon/2,
         maybe_fence/2, paused/2, silent/4, send_handover/2, rebalance/3]).
-export([mode/1, silent_poll_ms/1, node_of/1]).

-include("evatar_ha_instance.hrl").

-define(PLACE_RETRY_MS, 1000).

-type view() :: evatar_ha_instance:view().
-type effects() :: [evatar_ha_instance:decision()].

%% ---------------------------------------------------------------------------
%% Elections and registrations: evatar_ha_core decides, this says what
%% each outcome means for the instance
%% ---------------------------------------------------------------------------

%% @doc An event of `evatar_ha_core', and what its outcome means here.
-spec core(evatar_ha_core:event(), view(), #inst{}) -> {#inst{}, effects()}.
core(Event, V, #inst{role = Role, core = Core} = S) ->
    Ctx = (core_ctx(Role, V))#{keep_standby => keeps_standby(V, S)},
    {Core1, Effects} = evatar_ha_core:handle(Event, Ctx, Core),
    core_effects(Effects, V, S#inst{core = Core1}, []).

%% @doc What `evatar_ha_core' needs to know of the instance and the view.
-spec core_ctx(evatar_ha_core:role(), view()) -> evatar_ha_core:ctx().
core_ctx(Role, #{nodes := Nodes, heartbeat_ms := Hb, suspect_ms := Suspect} = V) ->
    Ctx = #{nodes => Nodes, heartbeat_ms => Hb, suspect_ms => Suspect, epoch => epoch(V),
            role => Role},
    maps:merge(Ctx, maps:with([self], V)).

core_effects([{vote, Node, Ec, Claim, Dead} | Rest], V, S, Acc) ->
    Active = case S of
                 #inst{role = standby, active = A} -> A;
                 #inst{me = Me} -> Me
             end,
    core_effects(Rest, V, S, [{vote, Node, Ec, Claim, Active, Dead} | Acc]);
core_effects([{restore_vote, _, _, _} = E | Rest], V, S, Acc) ->
    core_effects(Rest, V, S, [E | Acc]);
core_effects([{Kind, _, _} = E | Rest], V, S, Acc) when Kind =:= register; Kind =:= timer ->
    core_effects(Rest, V, S, [E | Acc]);
core_effects([{pause, keep} | Rest], V, S, Acc) ->
    core_effects(Rest, V, S, Acc);
core_effects([{pause, await} | Rest], V, S, Acc) ->
    core_effects(Rest, V, S#inst{reconfirming = true}, Acc);
core_effects([{pause, reconfirm} | Rest], V, #inst{core = Core} = S, Acc) ->
    Log = {log, notice, #{what => reconfirming_after_pause, claim => evatar_ha_core:claim(Core)}},
    core_effects(Rest, V, S#inst{reconfirming = true}, [Log | Acc]);
core_effects([Decision], V, S, Acc) ->
    {S1, Effects} = decided(Decision, V, S),
    {S1, lists:reverse(Acc, Effects)};
core_effects([], _V, S, Acc) ->
    {S, lists:reverse(Acc)}.

decided({won, handover, Ec}, V, #inst{role = standby, active = Old} = S) ->
    %% The old active becomes this one's standby, already in sync, with
    %% the claim {Ec, 1}.
    {S1, Effects} = take_over(handover, Ec, V, S),
    {Core, []} = evatar_ha_core:handle({claim, {Ec, 1}}, core_ctx(active, V), S1#inst.core),
    S2 = S1#inst{standby = Old, placing = false, core = Core},
    {S2, Effects ++ [{monitor, standby, Old}, {send, Old, {handover_done, Ec, {Ec, 1}}},
                     {synced_at, version(V)}, {flush, mode(S2)}, publish]};
decided({won, reelect, Ec}, V, #inst{role = active, standby = Sb, core = Core} = S)
  when Sb =/= undefined ->
    %% Re-elected with a standby (after a pause): it gets the claim {Ec, 1}
    %% in a snapshot after the new epoch, and the registration waits for its
    %% confirmation at Ec, as after a fence (a majority that recorded {Ec, 1}
    %% first would leave it stale, and what it confirmed lost).
    case keeps_standby(V, S) of
        true ->
            {S#inst{claiming = true},
             [{log, warning, #{what => reelected, epoch => Ec}},
              {logic, {reelected, Ec}, mode(S)}, {snapshot, Sb, evatar_ha_core:claim(Core)},
              publish]};
        false ->
            {S, [{log, warning, #{what => reelected, epoch => Ec}},
                 {logic, {reelected, Ec}, mode(S)}, publish]}
    end;
decided({won, reelect, Ec}, _V, #inst{role = active} = S) ->
    %% Re-elected above a stale promise while serving: the clients stay,
    %% only the epoch moves; effects wait for the registration of {Ec, 1}.
    {S, [{log, warning, #{what => reelected, epoch => Ec}}, {logic, {reelected, Ec}, mode(S)},
         publish]};
decided({won, keep_standby, Ec}, V, #inst{standby = Sb, core = Core} = S) ->
    %% A fenced active won again and keeps its standby, in sync: what was
    %% released is there. The standby gets the new claim {Ec, 1} with a
    %% snapshot taken after the takeover (so its confirmation carries Ec);
    %% that confirmation lets the registration go (evatar_ha_core), and the
    %% standby's confirmations release what goes out meanwhile.
    S1 = S#inst{role = active, active = undefined, watching = false, active_lost = false,
                claiming = true},
    {S1, [{log, warning, #{what => takeover, epoch => Ec, reason => fenced, version => version(V),
                           standby => node_of(Sb)}},
          {metric, evatar_takeovers_total, fenced}, serving, arm_logic_timers,
          {logic, {takeover, Ec}, mode(S1)}, {snapshot, Sb, evatar_ha_core:claim(Core)},
          {ensure_timer, silent, silent_poll_ms(maps:get(client_ack_timeout, V))}, publish,
          serve_held]};
decided({won, Why, Ec}, V, S) ->
    take_over(Why, Ec, V, S);
decided({lost, Why}, _V, #inst{role = standby} = S) ->
    stop(Why, S, [reply_held]);
decided({lost, Why}, _V, S) ->
    step_down(Why, S, []);
decided(registered, _V, #inst{standby = Sb} = S) when Sb =/= undefined ->
    %% A reconfirmation after a pause: the standby's confirmations still
    %% decide what goes out.
    {S#inst{reconfirming = false}, [reconfirmed]};
decided(registered, V, S) ->
    {S1, Place} = place(V, S#inst{reconfirming = false}),
    {S2, Soon} = place_soon(V, S1),
    {S2, [reconfirmed, release_all | Place ++ Soon]};
decided({fence, Why}, V, #inst{role = Role, core = Core} = S) ->
    Log = case Why of
              registration_timeout ->
                  {log, warning, #{what => registration_timeout,
                                   claim => evatar_ha_core:claim(Core)}};
              _ ->
                  {log, warning, #{what => registration_refused, reason => Why}}
          end,
    {S1, Effects} = case Role of
                        active -> fence_now(V, S);
                        _ -> {S, []}
                    end,
    {S1, [Log | Effects]}.

%% An instance that won the election at `Ec' takes over: a standby (fully
%% applied up to its version) or a fenced active asking again. It holds
%% every effect until the cluster accepted its new configuration; resumes
%% held while it was a standby are served now.
take_over(Why, Ec, V, #inst{standby = Sb} = S) ->
    S1 = S#inst{role = active, active = undefined, watching = false, active_lost = false,
                standby = undefined},
    Reason = case Why of
                 {R, _} -> R;
                 R -> R
             end,
    {S1, [{demonitor, active}, {demonitor, standby}] ++ [{send, Sb, dismiss} || Sb =/= undefined]
     ++ [{log, warning, #{what => takeover, epoch => Ec, reason => Why, version => version(V)}},
         {metric, evatar_takeovers_total, Reason}, serving, unsync, arm_logic_timers,
         {logic, {takeover, Ec}, mode(S1)},
         {ensure_timer, silent, silent_poll_ms(maps:get(client_ack_timeout, V))}, publish,
         serve_held]}.

%% A newer active exists: close the clients (they resume there) and go.
-spec step_down(term(), #inst{}, effects()) -> {#inst{}, effects()}.
step_down(Why, S, Pre) ->
    {S, Pre ++ [{log, warning, #{what => stepping_down, reason => Why}},
                {metric, evatar_step_downs_total},
                {disconnect_all, stale_epoch, <<"a newer instance of this pairing is active">>},
                {stop, Why}]}.

%% @doc The instance stops (after the effects `Pre').
-spec stop(term(), #inst{}, effects()) -> {#inst{}, effects()}.
stop(Why, S, Pre) ->
    {S, Pre ++ [{log, info, #{what => instance_stopped, reason => Why}}, {stop, Why}]}.

%% @doc Lets the standby go: dismissed, unmonitored, the commit unsynced.
-spec forget_standby(#inst{}) -> {#inst{}, effects()}.
forget_standby(#inst{standby = Sb} = S) ->
    {S#inst{standby = undefined, claiming = false},
     [{demonitor, standby}] ++ [{send, Sb, dismiss} || Sb =/= undefined] ++ [unsync]}.

%% ---------------------------------------------------------------------------
%% Fencing and pauses
%% ---------------------------------------------------------------------------

%% In a cluster of 3 or more: no majority and no word from the standby's
%% node within the lease.
-spec maybe_fence(view(), #inst{}) -> {#inst{}, effects()}.
maybe_fence(#{nodes := Nodes, majority := Majority, heard := Heard} = V, #inst{standby = Sb} = S) ->
    StandbyHeard = Sb =/= undefined andalso lists:member(node_of(Sb), Heard),
    case evatar_ha_core:must_fence(length(Nodes), Majority, StandbyHeard) of
        true -> fence_now(V, S);
        false -> {S, []}
    end.

%% Stops serving: every client is closed with Fenced (they go to their
%% other endpoints), nothing goes out; with a majority heard it asks for
%% the pairing again at once (an election in which its standby may win).
fence_now(#{majority := Majority} = V, S) ->
    S1 = S#inst{role = fenced, claiming = false},
    {S2, Elect} = case Majority of
                      true -> core({elect, fenced, false}, V, S1);
                      false -> {S1, []}
                  end,
    {S2#inst{reconfirming = false},
     [{log, warning, #{what => fenced}}, {metric, evatar_fenced_total},
      {disconnect_all, fenced, <<"this node lost the majority of the cluster">>}
      | Elect] ++ [publish, reconfirmed]}.

%% This node was paused itself while this instance was active (SIGSTOP, a
%% laptop lid, a long GC): decided by evatar_ha_core:after_pause/2. Nothing
%% is fenced for the pause alone.
-spec paused(view(), #inst{}) -> {#inst{}, effects()}.
paused(V, S) ->
    {S1, Effects} = core(paused, V, S),
    {S1, [pause_seen | Effects]}.

%% ---------------------------------------------------------------------------
%% The standby: placed by the active on the next alive node
%% ---------------------------------------------------------------------------

%% A fenced active that wins again keeps its standby when that one is in
%% sync and its node alive (else it takes over alone, as a standby does).
keeps_standby(V, #inst{role = Role, standby = Sb})
  when Sb =/= undefined, Role =:= fenced orelse Role =:= active ->
    synced(V) andalso lists:member(node_of(Sb), maps:get(alive, V, []));
keeps_standby(_V, _S) ->
    false.

wants_standby(#{nodes := Nodes, standby_opt := Opt},
              #inst{role = active, standby = undefined, placing = false}) ->
    Opt andalso length(Nodes) > 1;
wants_standby(_V, _S) ->
    false.

%% @doc A standby placed at once, if one is wanted.
-spec place_soon(view(), #inst{}) -> {#inst{}, effects()}.
place_soon(V, S) ->
    case wants_standby(V, S) of
        true -> {S, [{timer, place, 0}]};
        false -> {S, []}
    end.

%% Asks the next alive node to start a standby; tried again later when
%% nothing came of it.
-spec place(view(), #inst{}) -> {#inst{}, effects()}.
place(V, #inst{me = Me, standby_node = Preferred} = S) ->
    case wants_standby(V, S) of
        true ->
            #{nodes := Nodes, alive := Alive} = V,
            case evatar_ha_membership:standby_node(Nodes, node_of(Me), Alive, Preferred) of
                none -> {S, []};
                Node -> {S#inst{placing = true}, [{start_standby, Node},
                                                  {timer, place, ?PLACE_RETRY_MS}]}
            end;
        false ->
            {S, []}
    end.

%% ---------------------------------------------------------------------------
%% Silent client links, and the planned handover they start
%% ---------------------------------------------------------------------------

%% `Unacked': each entity's oldest unacknowledged delivery (system ms).
%% Deliveries still held for a registration were never sent: their
%% receivers are not silent.
-spec silent([{binary(), integer()}], integer(), view(), #inst{}) -> {#inst{}, effects()}.
silent(Unacked, Now, #{client_ack_timeout := Timeout} = V, #inst{core = Core, standby = Sb} = S) ->
    Silent = [E || not evatar_ha_core:holding(Core), {E, T} <- Unacked, Now - T > Timeout],
    Drops = lists:append(
              [[{log, warning, #{what => silent_link, entity => E}},
                {metric, evatar_entities_dropped_total, silent_link},
                {drop, E, silent_link, <<"delivered signals were not acknowledged in time">>}]
               || E <- Silent]),
    Arm = {ensure_timer, silent, silent_poll_ms(Timeout)},
    case Silent =/= [] andalso maps:get(handover_on_silent_link, V) =:= true
        andalso Sb =/= undefined andalso synced(V) of
        true ->
            {S1, Effects} = hand_over(V, S),
            {S1, Drops ++ [Arm | Effects]};
        false ->
            {S, Drops ++ [Arm, {flush_maybe, mode(S)}]}
    end.

%% A planned handover to the synced standby (a silent link, or the
%% rebalancer): it goes once the standby has confirmed everything.
hand_over(V, S) ->
    S1 = S#inst{role = handing_over},
    {S2, Send} = send_handover(V, S1),
    {S2, [{timer, handover, 4 * suspect(V)}, {flush, mode(S1)} | Send]}.

%% @doc The handover goes to the standby once it confirmed every version;
%% until then what is queued is shipped.
-spec send_handover(view(), #inst{}) -> {#inst{}, effects()}.
send_handover(V, #inst{standby = Sb} = S) when Sb =/= undefined ->
    case confirmed(V) =:= version(V) of
        true -> {S, [{send, Sb, {handover, version(V)}}]};
        false -> {S, [{flush, mode(S)}]}
    end;
send_handover(_V, S) ->
    {S, [{flush, mode(S)}]}.

%% A move of the rebalancer (evatar_placement): a planned handover, or the
%% standby moved to another node: dismissed, a configuration without it
%% registered as when its node is lost (effects held until a majority
%% accepted it), then a new standby placed there from a snapshot.
-spec rebalance(evatar_placement:move(), view(), #inst{}) -> {#inst{}, effects()}.
rebalance({handover, Id}, V, #inst{id = Id, standby = Sb} = S) ->
    {S1, Effects} = hand_over(V, S),
    {S1, [{log, notice, #{what => rebalance_handover, to => node_of(Sb)}} | Effects]};
rebalance({standby, Id, Node}, V, #inst{id = Id, standby = Sb, me = Me} = S) ->
    case Node =/= node_of(Me) andalso Node =/= node_of(Sb) of
        true ->
            {S1, Forget} = forget_standby(S#inst{standby_node = Node}),
            {S2, Effects} = core(standby_node_lost, V, S1),
            {S2, [{log, notice, #{what => rebalance_standby, from => node_of(Sb), to => Node}},
                  {standby_node, Node} | Forget] ++ Effects ++ [publish]};
        false ->
            {S, []}
    end;
rebalance(_Move, _V, S) ->
    {S, []}.

%% ---------------------------------------------------------------------------

suspect(#{suspect_ms := Ms}) -> Ms.
epoch(#{epoch := E}) -> E.
version(#{version := Ver}) -> Ver.
confirmed(#{confirmed := C}) -> C.
synced(#{synced := Synced}) -> Synced.

%% @doc How the output commit runs now: `replicated' with a standby,
%% `held' while a registration holds effects, else `direct'.
-spec mode(#inst{}) -> evatar_ha_commit:mode().
mode(#inst{standby = undefined, core = Core}) ->
    case evatar_ha_core:holding(Core) of
        true -> held;
        false -> direct
    end;
mode(#inst{}) -> replicated.

%% @doc How often silent client links are looked for.
-spec silent_poll_ms(pos_integer()) -> pos_integer().
silent_poll_ms(Timeout) -> max(50, Timeout div 2).

%% @doc The node of an instance: a pid's, or the model's `{Node, Ref}'.
-spec node_of(term()) -> node() | undefined.
node_of(Pid) when is_pid(Pid) -> node(Pid);
node_of({Node, _}) when is_atom(Node) -> Node;
node_of(_) -> undefined.
