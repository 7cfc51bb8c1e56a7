%% @doc PropEr state machine model of a pairing's lifecycle, run against the
%% real evatar API with `evatar_test_entity' processes as entities: joins
%% (good and bad credentials), descriptions of changing shape, signals
%% between any two components (bound or not, owned or not), leaving, and the
%% crash of an entity's process. The model predicts every message each
%% entity receives, the binding reports, sequence numbers and the
%% registration list. Run by evatar_pairing_SUITE:lifecycle_model/1.
-module(evatar_pairing_statem).

-include_lib("proper/include/proper.hrl").

-export([prop_lifecycle/0]).
-export([initial_state/0, command/1, precondition/2, postcondition/3, next_state/3]).
-export([join/1, join_bad/1, describe/2, send/4, leave/1, crash/1, check/0]).
-export([summary/1]).

-define(PAIRING, <<"model">>).
-define(E, evatar_test_entity).
-define(IDS, [<<"va1">>, <<"va2">>, <<"av1">>, <<"av2">>, <<"av3">>]).

%% joined: entity id -> role; parts: registered entity id -> parts (a subset
%% of [1, 2], see component/2); order: registration order; seq: signals
%% delivered to each joined entity so far.
-record(model, {joined = #{} :: #{binary() => evatar:role()},
                parts = #{} :: #{binary() => [1 | 2]},
                order = [] :: [binary()],
                seq = #{} :: #{binary() => non_neg_integer()}}).

%% @doc The property: every command's observed effects match the model.
-spec prop_lifecycle() -> proper:outer_test().
prop_lifecycle() ->
    ?FORALL(Cmds, commands(?MODULE),
            begin
                setup(),
                {History, State, Result} = run_commands(?MODULE, Cmds),
                cleanup(),
                ?WHENFAIL(io:format("History: ~p~nState: ~p~nResult: ~p~n",
                                    [History, State, Result]),
                          aggregate(command_names(Cmds), Result =:= ok))
            end).

setup() ->
    {ok, _} = evatar:create_pairing(?PAIRING, #{agent_credential => <<"a">>,
                                                avatar_credential => <<"v">>,
                                                join_timeout => 600000,
                                                feedback_timeout => 600000}),
    ok.

cleanup() ->
    Pids = [Pid || {{entity, _}, {_, Pid}} <- get()],
    ok = evatar:delete_pairing(?PAIRING),
    lists:foreach(fun ?E:kill/1, Pids),
    [erase(K) || {{entity, _} = K, _} <- get()],
    _ = ?E:drain(),
    ok.

%% ---------------------------------------------------------------------------
%% Model
%% ---------------------------------------------------------------------------

role(<<"va", _/binary>>) -> agent;
role(_) -> avatar.

credential(agent) -> <<"a">>;
credential(avatar) -> <<"v">>.

%% Part 1 of an agent (emulator) consumes what part 1 of an avatar (light)
%% provides and the other way round; part 2 of an avatar (thermometer)
%% consumes what part 2 of an agent (sink) provides.
component(Id, 1) ->
    case role(Id) of agent -> <<Id/binary, "-emu">>; avatar -> <<Id/binary, "-light">> end;
component(Id, 2) ->
    case role(Id) of agent -> <<Id/binary, "-sink">>; avatar -> <<Id/binary, "-thermo">> end.

all_components() -> [component(Id, P) || Id <- ?IDS, P <- [1, 2]].

owner(Component, #model{parts = Parts}) ->
    case [Id || {Id, Ps} <- maps:to_list(Parts), P <- Ps, component(Id, P) =:= Component] of
        [Id] -> {Id, part_of(Id, Component)};
        [] -> undefined
    end.

part_of(Id, Component) ->
    hd([P || P <- [1, 2], component(Id, P) =:= Component]).

%% Bound pairs are always between an agent's and an avatar's part with the
%% same number, in either direction.
routable({A, P}, {B, P}) -> role(A) =/= role(B);
routable(_, _) -> false.

%% @private
-spec initial_state() -> #model{}.
initial_state() -> #model{}.

%% @private
-spec command(#model{}) -> proper_types:type().
command(#model{joined = Joined} = S) ->
    Ids = maps:keys(Joined),
    Always = [{3, {call, ?MODULE, join, [elements(?IDS)]}},
              {1, {call, ?MODULE, join_bad, [elements(?IDS)]}},
              {1, {call, ?MODULE, check, []}}],
    WithJoined = case Ids of
                     [] -> [];
                     _ -> [{describe_weight(S), {call, ?MODULE, describe,
                                [elements(Ids), frequency([{3, [1, 2]}, {1, [1]},
                                                           {1, [2]}, {1, []}])]}},
                           {6, ?LET(From, elements(Ids), send_call(From, S))},
                           {1, {call, ?MODULE, leave, [elements(Ids)]}},
                           {1, {call, ?MODULE, crash, [elements(Ids)]}}]
                 end,
    frequency(Always ++ WithJoined).

%% Entities that have joined but not registered are described soon, so
%% that most sequences reach a bound pairing.
describe_weight(#model{joined = Joined, parts = Parts}) ->
    case map_size(Joined) > map_size(Parts) of
        true -> 8;
        false -> 2
    end.

%% Mostly a component of the sender's own and a registered receiver, so that
%% most signals are routable and every bound pair is tried both ways; now
%% and then any component at all, for the refusals.
send_call(From, #model{parts = Parts}) ->
    Own = [component(From, P) || P <- [1, 2]],
    Registered = [component(Id, P) || {Id, Ps} <- maps:to_list(Parts), P <- Ps],
    Receivers = case Registered of
                    [] -> [{1, elements(all_components())}];
                    _ -> [{5, elements(Registered)}, {1, elements(all_components())}]
                end,
    {call, ?MODULE, send,
     [From, frequency([{5, elements(Own)}, {1, elements(all_components())}]),
      frequency(Receivers), elements([sensor_data, event, request_no_feedback])]}.

%% @private
-spec precondition(#model{}, term()) -> boolean().
precondition(#model{joined = J}, {call, _, C, [Id | _]})
  when C =:= describe; C =:= send; C =:= leave; C =:= crash ->
    is_map_key(Id, J);
precondition(_S, _Call) ->
    true.

expected_join(Id, #model{joined = J}) ->
    Agent = lists:member(agent, maps:values(J)),
    case role(Id) of
        _ when is_map_key(Id, J) -> {error, entity_exists};
        agent when Agent -> {error, occupied};
        _ -> ok
    end.

expected_send(From, Sender, Receiver, #model{parts = Parts} = S) ->
    case {is_map_key(From, Parts), owner(Sender, S), owner(Receiver, S)} of
        {false, _, _} -> {error, <<"NotDescribed">>};
        {true, {From, _} = SenderAt, ReceiverAt} ->
            case ReceiverAt of
                undefined -> {error, <<"UnknownReceiver">>};
                {Target, _} ->
                    case routable(SenderAt, ReceiverAt) of
                        true -> {deliver, Target};
                        false -> {error, <<"NotBound">>}
                    end
            end;
        {true, _, _} ->
            {error, <<"BadSender">>}
    end.

%% @private
-spec postcondition(#model{}, term(), term()) -> boolean().
postcondition(S, {call, _, join, [Id]}, {Result, Msgs}) ->
    Result =:= expected_join(Id, S) andalso Msgs =:= [];
postcondition(_S, {call, _, join_bad, [_]}, {Result, Msgs}) ->
    Result =:= {error, bad_credential} andalso Msgs =:= [];
postcondition(S, {call, _, describe, [Id, Parts]} = Call, {ok, Msgs}) ->
    reports_ok(next_state(S, ok, Call), Msgs, Id, Parts);
postcondition(S, {call, _, send, [From, Sender, Receiver, Context]}, {SigId, Msgs}) ->
    #model{seq = Seq} = S,
    case {expected_send(From, Sender, Receiver, S), Msgs} of
        {{deliver, Target},
         [{Target, {signal, #{id := SigId, context := Context, seq := N, epoch := 1}}}]} ->
            N =:= maps:get(Target, Seq) + 1;
        {{error, Code},
         [{From, {signal, #{context := error, in_reply_to := SigId, seq := N,
                            body := #{type := Code}}}}]} ->
            N =:= maps:get(From, Seq) + 1;
        _ ->
            false
    end;
postcondition(S, {call, _, C, [Id]} = Call, {ok, Msgs}) when C =:= leave; C =:= crash ->
    case is_map_key(Id, S#model.parts) of
        true -> reports_ok(next_state(S, ok, Call), Msgs, Id, none);
        false -> Msgs =:= []
    end;
postcondition(S, {call, _, check, []}, {Registry, #{entities := Order}, Phase, Msgs}) ->
    Expected = lists:sort([{Id, Role, is_map_key(Id, S#model.parts)}
                           || {Id, Role} <- maps:to_list(S#model.joined)]),
    Got = lists:sort([{Id, Role, R} || #{entity := Id, role := Role, registered := R} <- Registry]),
    Roles = [role(Id) || Id <- S#model.order],
    ExpectedPhase = case lists:member(agent, Roles) andalso lists:member(avatar, Roles) of
                        true -> bound;
                        false -> waiting
                    end,
    Expected =:= Got andalso Order =:= S#model.order andalso Phase =:= ExpectedPhase
        andalso Msgs =:= [];
postcondition(_S, _Call, _Result) ->
    false.

%% Every registered entity got exactly one report listing the registered
%% entities in registration order, and the parts described are the ones
%% reported as registered.
reports_ok(#model{order = Order}, Msgs, _Id, _Parts) ->
    Reports = [{To, Entities} || {To, {bound, #{entities := Entities}}} <- Msgs],
    length(Reports) =:= length(Msgs)
        andalso lists:sort([To || {To, _} <- Reports]) =:= lists:sort(Order)
        andalso lists:all(fun({_, Entities}) -> Entities =:= Order end, Reports).

%% @private
-spec next_state(#model{}, term(), term()) -> #model{}.
next_state(S, _Result, {call, _, join, [Id]}) ->
    case expected_join(Id, S) of
        ok -> S#model{joined = (S#model.joined)#{Id => role(Id)},
                      seq = (S#model.seq)#{Id => 0}};
        _ -> S
    end;
next_state(#model{parts = Parts, order = Order} = S, _Result, {call, _, describe, [Id, Ps]}) ->
    Order1 = case is_map_key(Id, Parts) of
                 true -> Order;
                 false -> Order ++ [Id]
             end,
    S#model{parts = Parts#{Id => Ps}, order = Order1};
next_state(#model{seq = Seq} = S, _Result, {call, _, send, [From, Sender, Receiver, _]}) ->
    To = case expected_send(From, Sender, Receiver, S) of
             {deliver, Target} -> Target;
             {error, _} -> From
         end,
    S#model{seq = Seq#{To => maps:get(To, Seq) + 1}};
next_state(S, _Result, {call, _, C, [Id]}) when C =:= leave; C =:= crash ->
    S#model{joined = maps:remove(Id, S#model.joined),
            parts = maps:remove(Id, S#model.parts),
            order = lists:delete(Id, S#model.order),
            seq = maps:remove(Id, S#model.seq)};
next_state(S, _Result, _Call) ->
    S.

%% ---------------------------------------------------------------------------
%% Commands against the real system
%% ---------------------------------------------------------------------------

%% Each command returns what it observed: its result, and every message the
%% entities received because of it.
flush() ->
    ?E:flush([Pid || {{entity, _}, {_, Pid}} <- get()]).

%% @private
-spec join(binary()) -> {term(), list()}.
join(Id) ->
    Role = role(Id),
    case ?E:start(?PAIRING, Role, Id, credential(Role)) of
        {ok, Session, Pid} ->
            put({entity, Id}, {Session, Pid}),
            {ok, flush()};
        Error ->
            {Error, flush()}
    end.

%% @private
-spec join_bad(binary()) -> {term(), list()}.
join_bad(Id) ->
    Role = role(Id),
    Wrong = credential(case Role of agent -> avatar; avatar -> agent end),
    {?E:start(?PAIRING, Role, Id, Wrong), flush()}.

%% @private
-spec describe(binary(), [1 | 2]) -> {term(), list()}.
describe(Id, Parts) ->
    {Session, _} = get({entity, Id}),
    Components = [case {role(Id), P} of
                      {agent, 1} -> {component(Id, 1), [{<<"ACTUATOR">>, <<"ActionFeedback">>}],
                                     [{<<"ACTUATOR">>, <<"TurnLightOn">>}]};
                      {agent, 2} -> {component(Id, 2), [{<<"SENSOR">>, <<"Temperature">>}], []};
                      {avatar, 1} -> {component(Id, 1), [{<<"ACTUATOR">>, <<"TurnLightOn">>}],
                                      [{<<"ACTUATOR">>, <<"action feedback">>}]};
                      {avatar, 2} -> {component(Id, 2), [{<<"SENSOR">>, <<"Status">>}],
                                      [{<<"SENSOR">>, <<"Temperature">>}]}
                  end || P <- Parts],
    Result = evatar:describe(Session, ?E:description(Id, Components)),
    {Result, flush()}.

%% @private
-spec send(binary(), binary(), binary(), bil:signal_context()) -> {binary(), list()}.
send(From, Sender, Receiver, Context) ->
    {Session, _} = get({entity, From}),
    SigId = integer_to_binary(erlang:unique_integer([positive])),
    ok = evatar:send(Session, ?E:signal(SigId, Context, Sender, Receiver)),
    %% A call after the cast, from the same process, returns after the
    %% pairing has handled the signal.
    {ok, _} = evatar:stats(?PAIRING),
    {SigId, flush()}.

%% @private
-spec leave(binary()) -> {ok, list()}.
leave(Id) ->
    {Session, Pid} = erase({entity, Id}),
    ok = evatar:leave(Session),
    Msgs = flush(),
    ok = ?E:stop(Pid),
    {ok, Msgs}.

%% @private
-spec crash(binary()) -> {ok, list()}.
crash(Id) ->
    {_Session, Pid} = erase({entity, Id}),
    ok = ?E:kill(Pid),
    ok = evatar_test_wait:until(fun() -> gone(Id) end, #{interval => 2, what => {gone, Id}}),
    {ok, flush()}.

%% Whether the pairing has handled the entity's death.
gone(Id) ->
    {ok, Registry} = evatar:registry(?PAIRING),
    not lists:any(fun(#{entity := E}) -> E =:= Id end, Registry).

%% @private
-spec check() -> {list(), map(), atom(), list()}.
check() ->
    {ok, Registry} = evatar:registry(?PAIRING),
    {ok, Bindings} = evatar:bindings(?PAIRING),
    [#{state := Phase}] = summary(?PAIRING),
    {Registry, Bindings, Phase, flush()}.

%% @doc The pairing's line of evatar:pairings() once it answers in time:
%% `unavailable' says it was busy past the 2 s inspection timeout (a loaded
%% machine), not what state it is in.
-spec summary(binary()) -> [map()].
summary(Id) ->
    evatar_test_wait:value({summary, Id},
                           fun() -> [P || #{id := I} = P <- evatar:pairings(), I =:= Id] end,
                           fun([#{state := unavailable}]) -> false; (_) -> true end).
