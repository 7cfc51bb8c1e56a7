%% @doc Internal. `GET /api/pairings/:id/graph': what the dashboard draws
%% of one pairing (docs/dashboard.md): its entities (connected or detached,
%% described or not, their components), the Body Mapping Registry's bound
%% entries, and every unbound entry with its reason (`NoProvider',
%% `ParametersMismatch'), its parameters and, per candidate provider, the
%% parameters that did not match (bil:explain_unbound/2). Read from this
%% node's instance (active or standby: a standby holds the same state), or
%% from the active's node when this node has none.
-module(evatar_web_graph).

-export([graph/1, local/1]).

%% @doc The route's handler (evatar_web_router).
-spec graph(evatar_web_router:request()) -> evatar_web_router:reply().
graph(#{bindings := #{<<"id">> := Id}}) ->
    Result = case local(Id) of
                 {error, not_found} -> remote(Id);
                 Other -> Other
             end,
    case Result of
        {ok, Graph} ->
            {200, Graph};
        {error, not_found} ->
            {error, 404, <<"not_found">>, <<"id">>,
             <<"no pairing '", (evatar_log:id(Id))/binary, "' on this cluster">>};
        {error, busy} ->
            {error, 503, <<"busy">>, <<"id">>, <<"the pairing did not answer in time">>}
    end.

remote(Id) ->
    case [N || {N, #{role := active}} <- evatar:ha_locate(Id), N =/= node()] of
        [Node | _] ->
            try erpc:call(Node, ?MODULE, local, [Id], 5000)
            catch
                error:{exception, undef, _} -> {error, not_found};
                _:_ -> {error, busy}
            end;
        [] ->
            {error, not_found}
    end.

%% @doc The graph of this node's instance of pairing `Id'.
-spec local(binary()) -> {ok, map()} | {error, not_found | busy}.
local(Id) ->
    case {evatar:registry(Id), evatar:bindings(Id)} of
        {{ok, Registry}, {ok, #{bound := Bound, unbound := Unbound}}} ->
            State = case evatar:ha_status(Id) of
                        {ok, #{role := Role}} -> Role;
                        {error, _} -> unavailable
                    end,
            Descriptions = [D || #{description := D} <- Registry, D =/= undefined],
            {ok, #{pairing => Id, node => node(), state => State,
                   entities => [entity(E) || E <- Registry],
                   bound => [bound(B) || B <- Bound],
                   unbound => [unbound(U, Index)
                               || Index <- [evatar_web_explain:index(Descriptions)], U <- Unbound]}};
        {{error, _} = Error, _} ->
            Error;
        {_, {error, _} = Error} ->
            Error
    end.

entity(#{entity := Id, role := Role, registered := Registered, description := D,
         attached := Attached, delivered := Delivered}) ->
    #{id => Id, role => Role, registered => Registered, attached => Attached,
      delivered => Delivered,
      components => case D of
                        undefined -> [];
                        #{components := Cs} ->
                            [#{id => C, services => [entry(S) || S <- Ss],
                               consumes => [entry(U) || U <- Us]}
                             || #{id := C, services := Ss, consumes := Us} <- Cs]
                    end}.

entry(#{category := C, type := T, parameters := Ps}) ->
    #{category => C, type => T, parameters => [[N, V] || {N, V} <- Ps]}.

bound(#{consumer := C, provider := P, category := Cat, type := T, score := S,
        candidates := N}) ->
    #{consumer => C, provider => P, category => Cat, type => T, score => S, candidates => N}.

unbound(#{consumer := #{entity := E, component := C} = Consumer, category := Cat, type := T,
          reason := Reason} = U, Index) ->
    {Candidates, More} = evatar_web_explain:explain(U, Index),
    Params = [Ps || #{entity_id := E1, components := Cs} <- evatar_web_explain:consumer(E, Index), E1 =:= E,
                    #{id := C1, consumes := Us} <- Cs, C1 =:= C,
                    #{category := Ca, type := Ty, parameters := Ps} <- Us, Ca =:= Cat, Ty =:= T],
    #{consumer => Consumer, category => Cat, type => T,
      reason => case Reason of
                    no_provider -> <<"NoProvider">>;
                    parameters_mismatch -> <<"ParametersMismatch">>
                end,
      parameters => [[N, V] || {N, V} <- case Params of [P | _] -> P; [] -> [] end],
      candidates => [#{provider => P, mismatches => [#{name => N, wanted => W, offered => O}
                                                     || {N, W, O} <- F]}
                     || #{provider := P, failed := F} <- Candidates],
      more_candidates => More}.
